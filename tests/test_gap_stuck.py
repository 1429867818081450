"""A backbone with stiction holds the neck where a recording left it: the next one starts at rest
but off upright (``neck_env.gap.rest.stuck_starts``). The diagnosis keeps such recordings and
simulates them from where they start, so that friction's own evidence -- a neck that stays put
until a muscle pulls it free -- is in the data it judges, not thrown away as "not at rest"."""

from __future__ import annotations

import json

import numpy as np
import pytest

from neck_env.gap.cli import main as gap_main
from neck_env.gap.model import Model, prepare, tilt_vec
from neck_env.gap.rest import not_at_rest, stuck_starts
from neck_env.gap.synthetic import generate
from neck_env.recording import read_dataset

FRICTION = {"backbone_friction": {"friction_Nm": 0.05}}  # the catalogue's top: ~1.9 deg dead band


@pytest.fixture(scope="module")
def stuck_ds(tmp_path_factory):
    ds_dir = tmp_path_factory.mktemp("stuck") / "ds"
    truth = generate(ds_dir, FRICTION, seed=3, n_recordings=8, duration_s=15.0,
                     temperatures=True, starts="cooled")
    return ds_dir, truth


def test_the_generator_leaves_a_sticking_neck_where_the_wait_for_rest_ends(stuck_ds, tmp_path):
    """With ``starts="cooled"`` each recording starts where the rig's wait for rest leaves the
    neck: springs within 3 K of ambient, and with 0.05 N m of friction held off upright by up
    to its dead band (1.90 deg at the defaults after a 7 A pulse and 300 s of cooling:
    the backbone and the cold antagonists' spring back against the friction); without
    friction upright, as with ``starts="upright"``."""
    _, truth = stuck_ds
    recs = truth["recordings"]
    assert np.hypot(*recs[0]["start_true_tilt_deg"]) < 1e-9
    held = [np.hypot(*r["start_true_tilt_deg"]) for r in recs[1:]]
    # anywhere inside the dead band, most at its edge (the neck creeps back until it sticks)
    assert min(held) > 0.3 and np.median(held) > 1.5 and max(held) < 2.1, held
    free = generate(tmp_path / "free", [], seed=3, n_recordings=8, duration_s=15.0,
                    temperatures=True, starts="cooled")
    assert max(np.hypot(*r["start_true_tilt_deg"]) for r in free["recordings"]) < 0.1
    with pytest.raises(ValueError, match="unknown starts 'warm'"):
        generate(tmp_path / "x", [], seed=3, starts="warm")


def test_stuck_starts_are_found_and_kept(stuck_ds, tmp_path):
    """Every start held clearly off upright is taken as where the neck was held, and none is
    excluded; a dataset whose neck returns upright has none, and one whose starts are bent
    *and moving* (a neck still returning) keeps them out as before (``test_gap_rest``)."""
    ds_dir, truth = stuck_ds
    ds = read_dataset(ds_dir)
    stuck = stuck_starts(ds)
    off = {r["file"][:-4]: np.hypot(*r["start_true_tilt_deg"]) for r in truth["recordings"]}
    assert {k for k, v in off.items() if v > 1.0} <= set(stuck), (off, sorted(stuck))
    for k, v in stuck.items():  # as read: within the sensor's offset and noise of the truth
        assert abs(np.hypot(*v) - off[k]) < 1.0
    assert not_at_rest(ds) == []
    free_dir = tmp_path / "free"
    generate(free_dir, [], seed=3, n_recordings=8, duration_s=15.0, temperatures=True,
             starts="cooled")
    assert stuck_starts(read_dataset(free_dir)) == {}
    # the rig's protocol names them in meta.json with the rest reading: then only those
    meta = json.loads((ds_dir / "meta.json").read_text())
    meta.update(rest_tilt_deg=[0.0, 0.0], stuck_starts_tilt_deg={"rec_02": [1.0, 0.0]})
    named = read_dataset(ds_dir)
    named.meta.update(meta)
    assert sorted(stuck_starts(named)) == ["rec_02"]


def test_the_model_starts_a_stuck_recording_where_it_was_read(stuck_ds):
    """At its first sample each stuck recording is predicted where it was read, whatever the
    reading's fitted zero; before the first command a model without friction has sprung back
    to that zero, the model with the rig's friction still holds the start."""
    ds_dir, _ = stuck_ds
    data = prepare(read_dataset(ds_dir))
    assert data.stuck.sum() >= 6
    model = Model(data)
    zero = {"offset_x_deg": 0.3, "offset_y_deg": -0.2}
    free, held = model.predict([zero, {**zero, "backbone_friction.friction_Nm": 0.05}])
    mx, my = tilt_vec(data.meas_theta, data.meas_phi)
    for r in np.flatnonzero(data.stuck):
        rows = np.flatnonzero(data.fit_rec == r)
        t = data.t[r][data.fit_idx[rows]] - data.t[r][0]
        t_cmd = t[np.argmax((data.cmd[r][data.fit_idx[rows]] > 0).any(axis=1))]
        assert t_cmd >= 1.0
        first, later = rows[0], rows[np.searchsorted(t, t_cmd - 0.3)]
        start = data.stuck_start_tilt_deg[r]
        for p in (free, held):
            assert np.hypot(p.tilt_x[first] - start[0], p.tilt_y[first] - start[1]) < 0.15
        assert np.hypot(free.tilt_x[later] - 0.3, free.tilt_y[later] + 0.2) < 0.05
        assert np.hypot(held.tilt_x[later] - start[0], held.tilt_y[later] - start[1]) < 0.3
        # and the data agree with the held one
        assert np.hypot(mx[later] - start[0], my[later] - start[1]) < 0.5


def test_neck_gap_names_the_friction_that_holds_the_neck(stuck_ds, tmp_path, capsys):
    """End to end: the dataset whose every recording after the first starts stuck names
    ``backbone_friction`` near its true size, keeps every recording, lists them in the report
    and says so on the console."""
    ds_dir, _ = stuck_ds
    out = tmp_path / "rep.json"
    assert gap_main([str(ds_dir), "--json", str(out), "--no-plots"]) == 0
    rep = json.loads(out.read_text())
    console = capsys.readouterr().out
    assert rep["not_at_rest"] == [] and len(rep["stuck_starts"]) >= 6
    assert "start at rest off the rest reading" in console
    assert rep["verdict"] == ["backbone_friction"], rep["verdict"]
    fric = next(e for e in rep["effects"] if e["name"] == "backbone_friction")
    assert fric["params"]["friction_Nm"] == pytest.approx(0.05, rel=0.3)
    assert fric["heldout_reduction"] > 0.5
