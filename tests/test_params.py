"""Parameter validation, JSON round trip and provenance."""

import json

import pytest

from neck_env.params import DEFAULT_PARAMS_PATH, NeckParams, default_params


def test_default_params_are_the_committed_calibration():
    p = default_params()
    assert DEFAULT_PARAMS_PATH.exists()
    assert p == NeckParams.load(DEFAULT_PARAMS_PATH)
    assert p.provenance["thermal.convection_W_m2K"].startswith("fitted")
    assert p.provenance["head.mass_kg"].startswith("paper")
    assert p.provenance["material.youngs_austenite_Pa"].startswith("datasheet")


def test_json_round_trip(tmp_path):
    p = default_params().replace(source="test", thermal__ambient_C=22.5)
    path = tmp_path / "p.json"
    p.save(path)
    q = NeckParams.load(path)
    assert q == p
    assert q.provenance["thermal.ambient_C"] == "test"
    assert q.muscles.azimuths_deg == p.muscles.azimuths_deg


@pytest.mark.parametrize("change, field", [
    (dict(spring__wire_diameter_m=-0.8e-3), "spring.wire_diameter_m"),
    (dict(material__Af_C=60.0), "material.Af_C"),  # below A_s
    (dict(material__Ms_C=30.0), "material.Ms_C"),  # below M_f
    (dict(thermal__convection_W_m2K=float("nan")), "thermal.convection_W_m2K"),
    (dict(backbone__bending_stiffness_Nm2=0.0), "backbone.bending_stiffness_Nm2"),
    (dict(muscles__pennation_deg=75.0), "muscles.pennation_deg"),
    (dict(spring__coil_diameter_m=1e-3), "spring.coil_diameter_m"),
    (dict(material__poisson_ratio=0.6), "material.poisson_ratio"),
])
def test_out_of_range_parameters_raise_naming_the_field(change, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        NeckParams().replace(**change)


def test_unknown_fields_in_json_are_named(tmp_path):
    data = default_params().to_dict()
    data["spring"]["wire_diamater_m"] = 1e-3
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="spring.wire_diamater_m"):
        NeckParams.load(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json"):
        NeckParams.load(path)


def test_replace_rejects_unknown_parameter():
    with pytest.raises(ValueError, match="thermal.h"):
        NeckParams().replace(thermal__h=3.0)
