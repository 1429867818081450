"""Sim-to-real gap diagnosis (``neck_env.gap``): the contract of design.md 2.3, the model it
fits against the simulator itself, the paper's phi offset, a small faithful blind evaluation
(the full one is ``benchmarks/gap_blind.py``) and bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Sequence

import gymnasium as gym
import numpy as np
import pytest

import neck_env  # noqa: F401  (registers NeckTrack-v0)
from neck_env import effects as fx
from neck_env.gap.cli import main as gap_main
from neck_env.gap.replay import replay_dataset
from neck_env.gap.synthetic import generate
from neck_env.params import NeckParams, default_params
from neck_env.physics import layout as L
from neck_env.physics.plant import constants_from_params, cooling_time_constant_s, simulate
from neck_env.recording import read_dataset, write_meta, write_recording

pytestmark = pytest.mark.slow

REPORT_KEYS = {"verdict", "effects", "localization", "unexplained", "ambiguous"}


def _diagnose(ds: Path, tmp_path: Path, name: str = "report", extra: Sequence[str] = ()) -> dict:
    out = tmp_path / f"{name}.json"
    rc = gap_main([str(ds), "--json", str(out), "--quiet", "--no-plots", *extra])
    assert rc == 0
    return json.loads(out.read_text())


def _check_contract(rep: dict) -> None:
    assert REPORT_KEYS <= set(rep)
    assert isinstance(rep["verdict"], list) and isinstance(rep["unexplained"], bool)
    assert {e["name"] for e in rep["effects"]} == set(fx.CATALOGUE)
    # ranked best first: the verdict's effects (the conclusion), then the rest by held-out gap
    names = [e["name"] for e in rep["effects"]]
    assert names[:len(rep["verdict"])] == rep["verdict"], (names, rep["verdict"])
    gaps = [e["heldout_gap_after"] for e in rep["effects"][len(rep["verdict"]):]]
    assert gaps == sorted(gaps), "effects must be ranked best first"
    for e in rep["effects"]:
        assert {"name", "params", "heldout_gap_before", "heldout_gap_after"} <= set(e)
        assert set(e["params"]) == set(fx.EFFECTS[e["name"]].params)
    shares = [loc["share"] for loc in rep["localization"]]
    assert rep["localization"] and all(0 <= s <= 1 for s in shares) and sum(shares) <= 1 + 1e-3  # shares are rounded to 4 decimals
    for a in rep["ambiguous"]:
        assert a["effect"] in fx.CATALOGUE and a["effect"] not in rep["verdict"]
        assert a["with"] and a["note"]
    for loc in rep["localization"]:
        assert loc["signal"] in ("theta", "phi", "temperature")
        assert loc["phase"] in ("heating", "cooling", "rest")
    # the export carries a structure the held-out data showed (the best on the tilt, or one the
    # temperatures show) and the terminals' path their check selected
    x = rep["export"]
    if x["evidence"] == "tilt":  # the best one held out
        best = min(rep["structure"], key=lambda c: c["heldout_gap_after"])
        assert x["structure"] == best["name"] and set(x["params"]) == set(best["params"]), x
        assert x["heldout_gap_structure_deg"] == pytest.approx(best["heldout_gap_after"], abs=1e-4), (x, best)
        assert x["exported"] == (x["terminals"] is not None or
                                 x["gap_all_recordings_with_deg"] < x["gap_all_recordings_without_deg"])
    elif x["evidence"] == "temperatures":  # shown where a tilt F test could not
        assert rep["temperatures_used"] and x["exported"], x
        assert x["heldout_T_rms_structure_C"] <= 0.8 * x["heldout_T_rms_nominal_C"], x
    else:  # only the terminals' path the held-out temperatures selected is carried then
        assert x["structure"] is None and x["exported"] == (x["terminals"] is not None), x
    assert (x["terminals"] is not None) == bool((rep["calibration"].get("terminals") or {}).get("selected"))
    # the replay's IMU offset and thermistor lag are the exported fit's, not the nominal refit's
    assert set(x["sensors"]) == {"offset_x_deg", "offset_y_deg", "thermistor_lag_s"}
    if not x["exported"]:  # the files hold the verdict model: so do the sensors
        cp = rep["corrected"]["params"]
        for k, v in x["sensors"].items():
            assert v == pytest.approx(cp.get(k, 0.0), abs=1e-5), (k, x["sensors"], cp)
    assert [a["effect"] for a in rep["absorption"]] == list(fx.CATALOGUE)
    for a in rep["absorption"]:
        assert a["heldout_size_deg"] >= 0 and a["heldout_left_deg"] >= 0
        assert 0 <= a["absorbed"] <= 1
        assert bool(a["separate"]) == (a["absorbed"] >= 0.8 and not a["seen_in_temperatures"]), a


def _write_pulses(ds: Path, params, plan, dt: float = 0.02, length_s: float = 20.0,
                  temperatures: bool = False) -> None:
    """Noise-free recordings of ``params``: each entry ``(muscles, amps)`` of ``plan`` powers
    its muscles at that current from 1 to 6 s; with ``temperatures`` the springs' T1..T3 too."""
    consts = constants_from_params(params)
    ambient = params.thermal.ambient_C
    for k, (muscles, amps) in enumerate(plan):
        steps = int(length_s / dt)
        cur = np.zeros((steps, 1, 3))
        t = (np.arange(steps) + 1) * dt
        for m in muscles:
            cur[(t > 1.0) & (t <= 6.0), 0, m] = amps
        traj, _ = simulate(consts, cur, dt)
        # row j holds the current commanded during (t_j, t_j + dt]: shift by one sample
        cols = {"t": np.concatenate([[0.0], t[:-1]]),
                "i1": cur[:, 0, 0], "i2": cur[:, 0, 1], "i3": cur[:, 0, 2],
                "theta_deg": np.concatenate([[0.0], traj.theta_deg[:-1, 0]]),
                "phi_deg": np.concatenate([[0.0], traj.phi_deg[:-1, 0]]) % 360.0}
        if temperatures:
            cols.update({f"T{m + 1}": np.concatenate([[ambient], traj.T_C[:-1, 0, m]])
                         for m in range(3)})
        write_recording(ds / f"rec_{k + 1:02d}.csv", cols)
    write_meta(ds, {"ambient_C": ambient, "sample_hz": 1 / dt})


def test_noise_free_nominal_data_is_matched_exactly(tmp_path):
    """Recordings made by the calibrated simulator itself (no noise, no effect): the nominal
    refit leaves no gap and nothing is blamed. Checks that the diagnosis fits the project's own
    plant, not a private copy of it."""
    ds = tmp_path / "nominal"
    plan = [(0, 6.0), (1, 7.0), (2, 5.0), (0, 8.0), (1, 4.5), (2, 6.5)]
    _write_pulses(ds, default_params(), [([m], amps) for m, amps in plan], temperatures=True)
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    assert rep["verdict"] == [] and rep["unexplained"] is False
    assert rep["effects"][0]["heldout_gap_before"] < 0.05  # degrees, on held-out recordings
    te = rep["calibration"]["params"]["thermoelastic_scale"]
    assert te["value"] == pytest.approx(1.0, abs=0.15), te
    # what a baseline shift hides of each effect on these recordings: a payload on an upright
    # neck is a softer backbone (its gravity moment grows with the tilt as the elastic one
    # does), while no baseline parameter shifts every edge in time as a delay does
    hidden = {a["effect"]: a for a in rep["absorption"]}
    assert hidden["head_payload"]["absorbed"] > 0.7 and "EI_scale" in hidden["head_payload"]["by"]
    assert hidden["actuation_delay"]["absorbed"] < 0.5
    # coupling's tilt a larger h and heat capacity hide, but the thermistors recorded here see
    # the unpowered springs warm, which no baseline shift does
    assert hidden["thermal_coupling"]["seen_in_temperatures"] and not hidden["thermal_coupling"]["separate"]
    assert not hidden["head_payload"]["seen_in_temperatures"]
    # 6 short pulses barely wear the springs; the catalogue's draft starts at the middle
    # recording, and the split holds out the first and third (the 4.5 A pulse, the lowest
    # current, is fitted: held-out recordings stay inside the fitted currents)
    assert rep["heldout_recordings"] == ["rec_01", "rec_03"], rep["heldout_recordings"]
    assert all(a["heldout_size_deg"] > 0.05 for a in hidden.values()
               if a["effect"] not in ("sma_fatigue", "convection_change")), hidden


def test_stiffer_cold_springs_are_this_rigs_baseline_not_a_softer_backbone(tmp_path):
    """A rig whose cold (martensite) springs are twice as stiff -- another wire lot, springs
    wound with fewer turns -- bends about half as far at every current. The other baseline
    parameters (EI, C_A, gamma_L, a warm spring's thermoelastic tension ...) make up most of
    it, not all: the antagonists' share of the stiffness sets how the bend grows with the
    transformed fraction (without ``EM_scale`` 0.034 deg stays on these held-out recordings;
    with it 0.019). With ``--fit-spring-modulus`` the baseline's martensite modulus is fitted,
    identified and reported; nothing is blamed on an effect either way."""
    base = default_params()
    rig = base.replace(material__youngs_martensite_Pa=2.0 * base.material.youngs_martensite_Pa)
    plan = [([0], 6.0), ([1], 7.0), ([2], 5.0), ([0, 1], 6.5), ([1], 8.0), ([1, 2], 5.5),
            ([2], 6.5), ([0], 4.5)]
    ds = tmp_path / "stiff"
    _write_pulses(ds, rig, plan)
    rep = _diagnose(ds, tmp_path, extra=["--fit-spring-modulus"])
    assert rep["verdict"] == [] and rep["unexplained"] is False
    assert rep["nominal"]["heldout_gap"] < 0.02, rep["nominal"]  # degrees (bends of 5-20 deg)
    em = rep["calibration"]["params"]["EM_scale"]
    # the cold springs' rate trades with a warm spring's thermoelastic tension and C_A (both
    # fitted): these recordings read x2 as x1.4 with 0.75 of the paper's tension and C_A x0.79,
    # 0.019 deg from the truth, which the priors on EM and C_A charge more for than that
    assert 1.25 < em["value"] < 2.4 and em["identified"], em
    # by default the modulus is the paper's, and the other parameters make up most of it
    plain = _diagnose(ds, tmp_path, "plain")
    assert "EM_scale" not in plain["calibration"]["params"]
    assert 0.03 < plain["nominal"]["heldout_gap"] < 0.1, plain["nominal"]


def test_springs_without_thermoelastic_tension_are_this_rigs_baseline(tmp_path):
    """The paper's constitutive law (eq. 1) adds a thermoelastic tension to a warm spring
    (Brinson's 0.55 MPa/K); a coil spring's thermal expansion barely moves it, and both rigs
    written apart from this model leave it out. A rig without it bends differently wherever a
    warm spring is stretched -- most where one muscle pulls against another still warm. The
    baseline fits its scale: here it finds ~0, identified, and leaves no gap and no effect;
    the export carries it."""
    base = default_params()
    rig = base.replace(material__thermoelastic_Pa_per_K=0.0)
    plan = [([0], 6.0), ([1], 7.0), ([2], 5.0), ([0, 1], 6.5), ([1], 8.0), ([1, 2], 5.5),
            ([2], 6.5), ([0], 4.5)]
    ds = tmp_path / "no_thermoelastic"
    _write_pulses(ds, rig, plan, temperatures=True)
    rep = _diagnose(ds, tmp_path)
    assert rep["verdict"] == [] and rep["unexplained"] is False
    assert rep["nominal"]["heldout_gap"] < 0.03, rep["nominal"]  # degrees (bends of 5-20 deg)
    te = rep["calibration"]["params"]["thermoelastic_scale"]
    assert te["value"] < 0.2 and te["identified"], te
    exported = NeckParams.load(rep["outputs"]["params"]).material.thermoelastic_Pa_per_K
    assert exported < 0.2 * base.material.thermoelastic_Pa_per_K


def test_heat_drained_into_the_terminals_is_this_rigs_baseline_not_a_higher_h(tmp_path):
    """A rig whose springs lose heat to their crimps and posts as well as to the air (here half
    as much again, into terminals of 1.5 J/K that shed 0.8 of it: not the model's own form of
    the path, which sheds twice the conductance) cools fast while the terminals are cold and
    slowly once they are warm. A single thermal node per spring can follow only the mix, and
    its h came out that much too high; with the terminals in the baseline h is this rig's
    convection and the path is fitted, identified and reported. Nothing is blamed."""
    base = default_params()
    hA = constants_from_params(base)[0, L.HA]
    rig = base.replace(thermal__terminal_conductance_W_K=0.5 * hA,
                       thermal__terminal_loss_W_K=0.4 * hA, thermal__terminal_heat_capacity_J_K=1.5)
    plan = [([0], 6.0), ([1], 7.0), ([2], 5.0), ([0, 1], 6.5), ([1], 8.0), ([1, 2], 5.5),
            ([2], 6.5), ([0], 4.5)]
    ds = tmp_path / "terminals"
    _write_pulses(ds, rig, plan, length_s=30.0, temperatures=True)
    rep = _diagnose(ds, tmp_path, extra=["--fit-terminals"])
    assert rep["verdict"] == [] and rep["unexplained"] is False
    cal = rep["calibration"]
    assert cal["params"]["h_scale"]["value"] == pytest.approx(1.0, rel=0.15), cal["params"]["h_scale"]
    share = cal["params"]["terminal_share"]
    assert 0.3 < share["value"] < 0.8 and share["identified"], share
    assert cal["cooling_time_constant_s"]["value"] == pytest.approx(cooling_time_constant_s(base), rel=0.15)
    # the export carries the path: NeckTrack-v0 loaded from it replays this rig
    assert NeckParams.load(rep["outputs"]["params"]).thermal.terminal_conductance_W_K > 0
    replay, defaults = _replay_export_and_defaults(ds, rep)
    print("replay RMS per recording, export", np.round(replay, 3), "defaults", np.round(defaults, 3))
    assert np.median(replay) < 0.1 and np.median(replay) < 0.5 * np.median(defaults), (replay, defaults)
    # without the option the plain baseline judges the effects, and the path is checked on the
    # held-out thermistors: these need it, so h and the time constant come from it
    plain = _diagnose(ds, tmp_path, "plain")
    assert plain["verdict"] == [] and "terminal_share" not in plain["calibration"]["params"]
    check = plain["calibration"]["terminals"]
    assert check["selected"], check
    assert check["heldout_T_F"] > check["heldout_T_F_crit"], check
    h_plain = check["without_terminals"]["convection_W_m2K"]["value"]
    h_true = base.thermal.convection_W_m2K
    assert h_plain > 1.3 * h_true, h_plain  # the one-node baseline reads the path as a larger h
    h = plain["calibration"]["convection_W_m2K"]
    assert h["value"] == pytest.approx(h_true, rel=0.15) and "terminals" in h["source"], h


def test_one_thermistor_that_drops_out_still_pins_this_rigs_cooling(tmp_path):
    """A rig with a thermistor on muscle 1's spring only, whose wire comes loose now and then
    (a quarter of its readings missing, scattered, and a 3 s stretch in every recording), on
    springs that cool at half the model's h. The readings it has enter the fit: h comes out at
    this rig's value and tighter than from the tilt alone, nothing is blamed, and the report
    says what the temperatures rest on."""
    base = default_params()
    rig = base.replace(thermal__convection_W_m2K=0.5 * base.thermal.convection_W_m2K)
    plan = [([0], 6.0), ([1], 7.0), ([2], 5.0), ([0, 1], 6.5), ([0], 8.0), ([1, 2], 5.5),
            ([2], 6.5), ([0], 4.5)]
    full, one, none = tmp_path / "full", tmp_path / "one", tmp_path / "none"
    _write_pulses(full, rig, plan, length_s=30.0, temperatures=True)
    rng = np.random.default_rng(3)
    for out in (one, none):
        out.mkdir()
        (out / "meta.json").write_text((full / "meta.json").read_text())
    for rec in read_dataset(full).recordings:
        cols = {k: v for k, v in rec.columns().items() if k not in ("T1", "T2", "T3")}
        write_recording(none / f"{rec.name}.csv", cols)
        t1 = rec.temperatures_C[:, 0].copy()
        t1[rng.random(t1.size) < 0.25] = np.nan
        t1[(rec.t > 8.0) & (rec.t < 11.0)] = np.nan  # the wire off for 3 s while cooling
        write_recording(one / f"{rec.name}.csv", dict(cols, T1=t1))
    assert "T2" not in (one / "rec_01.csv").read_text().splitlines()[0]
    assert any(line.endswith(",") for line in (one / "rec_01.csv").read_text().splitlines())
    rep = _diagnose(one, tmp_path, "one")
    _check_contract(rep)
    # no terminals on this rig: the check leaves h to the plain baseline
    assert rep["calibration"]["terminals"]["selected"] is False, rep["calibration"]["terminals"]
    assert rep["verdict"] == [] and rep["temperatures_used"] is True
    read = rep["temperature_readings"]
    assert read["T2"] == read["T3"] == 0.0 and 0.6 < read["T1"] < 0.75, read
    h = rep["calibration"]["params"]["h_scale"]
    assert h["value"] == pytest.approx(0.5, rel=0.15), h
    assert rep["calibration"]["cooling_time_constant_s"]["value"] == pytest.approx(
        cooling_time_constant_s(rig), rel=0.15)
    tilt_only = _diagnose(none, tmp_path, "none")
    assert tilt_only["temperatures_used"] is False and tilt_only["temperature_readings"] == {}
    h0 = tilt_only["calibration"]["params"]["h_scale"]
    print("h_scale with one thermistor", h, "tilt only", h0)
    assert h["std"] < h0["std"], (h, h0)


def test_paper_phi_offset_is_imu_misalignment(tmp_path):
    """The paper's own gap: phi settles off 180/60/300 deg, which the authors blame on the IMU
    mount. Its experiments (5 s pulses at 4-5 A and 6-8 A, no thermistors) on a rig whose IMU is
    rotated 8 deg about the head axis and tilted 6 deg on its mount (the catalogue's largest;
    the baseline's zero offset carries the tilt, and at +-4 deg it could not): the tool names
    imu_misalignment, recovers the yaw, and the corrected model it exports loads into
    NeckTrack-v0."""
    ds = tmp_path / "paper"
    generate(ds, {"imu_misalignment": {"yaw_deg": 8.0, "tilt_deg": 6.0, "tilt_dir_deg": 90.0}},
             seed=5, protocol="paper", temperatures=False)
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    assert rep["verdict"] == ["imu_misalignment"] and rep["unexplained"] is False
    best = rep["effects"][0]
    assert best["name"] == "imu_misalignment"
    assert abs(best["params"]["yaw_deg"] - 8.0) < 1.0
    assert best["heldout_gap_after"] < 0.25 * best["heldout_gap_before"]
    # the exported corrected model drives the env
    params_path = rep["outputs"]["params"]
    effects = json.loads(Path(rep["outputs"]["effects"]).read_text())
    assert set(effects) == {"imu_misalignment"}
    env = gym.make("NeckTrack-v0", params=params_path, effects=effects)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.array([6.0, 0.0, 0.0], np.float32))
    assert np.all(np.isfinite(obs))
    env.close()


def _replay_export_and_defaults(ds: Path, rep: dict) -> tuple[np.ndarray, np.ndarray]:
    """Replay errors (per recording, deg) of the first four recordings in NeckTrack-v0 built
    from the report's export (with its fitted IMU zero offset) and from the defaults."""
    out = replay_dataset(ds, rep, recordings=4)
    return out["exported_deg"], out["defaults_deg"]


def test_replay_takes_the_sensors_of_the_exported_fit_and_an_older_reports_calibration():
    from neck_env.gap.replay import report_offset_deg, report_thermistor_lag_s

    cal = {"params": {"offset_x_deg": {"value": -0.19}, "offset_y_deg": {"value": 0.21},
                      "thermistor_lag_s": {"value": 2.0}}}
    older = {"calibration": cal}
    assert report_offset_deg(older).tolist() == [-0.19, 0.21]
    assert report_thermistor_lag_s(older) == 2.0
    rep = {"calibration": cal, "export": {"sensors": {"offset_x_deg": -0.10, "offset_y_deg": 0.24,
                                                      "thermistor_lag_s": 0.97}}}
    assert report_offset_deg(rep).tolist() == [-0.10, 0.24]
    assert report_thermistor_lag_s(rep) == 0.97


def test_the_export_benchmark_replays_the_rig_as_it_is_now(tmp_path):
    # benchmarks/gap_export.py: the export is the rig as it is now (a draft seen to start blows
    # in it), so only recordings from the draft's onset on are replayed
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from gap_export import as_now
    finally:
        sys.path.pop(0)
    from neck_env.gap import independent

    draft = {"convection_change": {"mode": "draft", "gain": 2.0, "from_recording_index": 3}}
    truth = independent.generate(tmp_path / "d", draft, seed=5, n_recordings=5, duration_s=8.0)
    assert as_now(truth) == [False, False, False, True, True]
    truth = independent.generate(tmp_path / "n", [], seed=5, n_recordings=5, duration_s=8.0)
    assert as_now(truth) == [True] * 5


def test_replay_refuses_a_report_without_an_export_and_a_missing_dataset(tmp_path, capsys):
    from neck_env.gap.replay import main as replay_main

    ds = tmp_path / "ds"
    _write_pulses(ds, default_params(), [([0], 6.0)], length_s=4.0)
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps({"verdict": [], "outputs": {}}))
    assert replay_main([str(ds), str(rep)]) == 2
    assert "outputs.params" in capsys.readouterr().err
    rep.write_text(json.dumps({"verdict": [], "outputs": {"params": str(tmp_path / "p.json")}}))
    assert replay_main([str(ds), str(rep)]) == 2
    assert "no calibration" in capsys.readouterr().err
    rep.write_text(json.dumps({"verdict": [], "outputs": {"params": str(tmp_path / "p.json")},
                               "calibration": {"params": {}}}))
    assert replay_main([str(tmp_path / "nowhere"), str(rep)]) == 2
    assert "nowhere" in capsys.readouterr().err


def test_replay_reads_the_tilt_through_an_exported_imu_misalignment(tmp_path):
    # A rig whose IMU sits yawed and tilted on the head, noise-free sensors and the defaults'
    # plant: the files carrying its misalignment replay it within the integrators' difference
    # (0.001-0.012 deg seen), the same plant without them misses by the mount's rotation of
    # every bend (2.1-3.3 deg seen; before, the replay left the misalignment out).
    from neck_env.sensors import SensorParams

    mis = {"yaw_deg": 6.0, "tilt_deg": 3.0, "tilt_dir_deg": 40.0}
    truth = generate(tmp_path / "ds", {"imu_misalignment": mis}, seed=4, jitter=0.0,
                     n_recordings=3, duration_s=15.0, temperatures=False,
                     sensors=SensorParams(0.0, 0.0, 0.0, 0.0, 0.0))
    (tmp_path / "p.json").write_text(json.dumps(truth["params"]))
    (tmp_path / "e.json").write_text(json.dumps(truth["effects"]))
    zero = {"offset_x_deg": {"value": 0.0}, "offset_y_deg": {"value": 0.0}}
    rep = {"outputs": {"params": str(tmp_path / "p.json"), "effects": str(tmp_path / "e.json")},
           "calibration": {"params": zero}}
    with_mount = replay_dataset(tmp_path / "ds", rep)["exported_deg"]
    # the console tool writes the same figures where asked
    from neck_env.gap.replay import main as replay_main
    (tmp_path / "r.json").write_text(json.dumps(rep))
    assert replay_main([str(tmp_path / "ds"), str(tmp_path / "r.json"),
                        "--json", str(tmp_path / "out.json")]) == 0
    doc = json.loads((tmp_path / "out.json").read_text())
    assert [r["name"] for r in doc["recordings"]] == ["rec_01", "rec_02", "rec_03"]
    assert [r["exported_deg"] for r in doc["recordings"]] == pytest.approx(with_mount, abs=1e-4)
    assert doc["recordings"][0]["exported_C"] is None and doc["median"]["exported_C"] is None
    (tmp_path / "e.json").write_text("{}")
    without = replay_dataset(tmp_path / "ds", rep)["exported_deg"]
    assert np.all(with_mount < 0.05), with_mount
    assert np.all(without > 4 * with_mount) and np.median(without) > 0.5, (with_mount, without)


# A small faithful version of benchmarks/gap_blind.py: the same generator, random magnitudes in
# the catalogue ranges, diagnosis through the CLI seeing only the folder. One effect from each
# kind of signature (timing, heat flow, across-recording trend, backbone mechanics), an
# effect-free rig and the out-of-catalogue gyro drift.
# Rigs with a "wide" baseline are far from the defaults (h x0.3-x4, temperatures +-15 C, ...).
BLIND = [
    ([], 1000, "wide"),
    (["actuation_delay"], 1006, "default"),
    (["thermal_coupling"], 1007, "wide"),
    (["convection_change"], 1008, "wide"),
    (["sma_fatigue"], 1009, "default"),
    (["backbone_friction"], 1010, "default"),
    (["gyro_bias_drift"], 1013, "wide"),
]


def _drop_imu_readings(path: Path) -> bool:
    """Blank the IMU cells of a few rows, as a logger does when an I2C read fails: single
    rows (theta and phi, or phi alone) and a run of four (0.1 s between the readings around
    it at 50 Hz). With a 0.05 s limit the run is refused before any fitting."""
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    th, ph = head.index("theta_deg"), head.index("phi_deg")
    for row, cols in ((100, (th, ph)), (400, (ph,)), (700, (th,)), *((k, (th, ph)) for k in range(1000, 1004))):
        cells = lines[row].split(",")
        for c in cols:
            cells[c] = "" if c == th else "nan"
        lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    bad = path.parent.parent / "refused.json"
    assert gap_main([str(path.parent), "--json", str(bad), "--quiet", "--imu-gap-max-s", "0.05"]) == 2
    assert not bad.exists()
    return True


@pytest.mark.parametrize("effects, seed, baseline", BLIND,
                         ids=[f"{e[0] if e else 'none'}-{b}" for e, _, b in BLIND])
def test_blind_small(tmp_path, effects, seed, baseline):
    ds = tmp_path / "ds"
    # the effect-free rig's wire comes on the command line instead of meta.json
    wire_on_cli = not effects
    truth = generate(ds, effects, seed=seed, baseline=baseline, wire_meta=not wire_on_cli)
    assert not (ds / "truth.json").exists() and Path(str(ds) + ".truth.json").exists()
    wire = ["--wire-diameter-mm", "0.8", "--wire-specific-heat", "837"] if wire_on_cli else []
    if wire_on_cli:  # metres where mm are due: refused before any fitting, nothing written
        assert gap_main([str(ds), "--json", str(tmp_path / "bad.json"), "--quiet",
                         "--wire-diameter-mm", "0.0008", "--wire-specific-heat", "837"]) == 2
        assert not (tmp_path / "bad.json").exists()
    dropped = effects == ["actuation_delay"] and _drop_imu_readings(ds / "rec_03.csv")
    rep = _diagnose(ds, tmp_path, extra=wire)
    _check_contract(rep)
    # IMU readings that did not arrive are filled, said, and the verdict does not need them
    assert rep["imu_gaps_filled"] == ([{"recording": "rec_03", "samples": 7,
                                        "longest_gap_s": pytest.approx(0.1)}] if dropped else [])
    if not effects:
        assert rep["verdict"] == [] and rep["unexplained"] is False
        # the baseline is recovered: h from the cooling tails and the wire meta.json gives
        # (its datasheet specific heat, not the rig's drawn one) within 25 % of the truth
        h = rep["calibration"]["convection_W_m2K"]
        assert h["identified"] and h["wire"] == "meta.json"
        assert abs(h["value"] / truth["physical"]["convection_W_m2K"] - 1) < 0.25
        assert rep["calibration"]["params"]["h_scale"]["identified"]
        tau = rep["calibration"]["cooling_time_constant_s"]
        assert tau["identified"]
        assert abs(tau["value"] / truth["physical"]["cooling_time_constant_s"] - 1) < 0.25
        # NeckTrack-v0 loaded from the export reproduces this rig (not the defaults' rig)
        exported, defaults = _replay_export_and_defaults(ds, rep)
        assert np.median(exported) < 0.15, exported
        assert np.all(exported < 0.1 * defaults), (exported, defaults)
    elif effects == ["gyro_bias_drift"]:
        # not in the catalogue: unexplained, and the residual left sits in the tilt signals
        assert rep["unexplained"] is True
        assert "gyro_bias_drift" not in [e["name"] for e in rep["effects"]]
        rem = rep["localization_remaining"]
        tilt = sum(loc["share"] for loc in rem if loc["signal"] in ("theta", "phi"))
        assert tilt > 0.5
    else:
        name = effects[0]
        assert rep["verdict"] == [name]
        # nothing left unexplained (fatigue's permanent set leaves the rest reading alone)
        assert rep["unexplained"] is False, rep["unexplained_reasons"]
        best = rep["effects"][0]
        assert best["name"] == name
        # the held-out gap shrinks by at least 60 % once the effect is added
        assert best["heldout_gap_after"] < 0.4 * best["heldout_gap_before"]
        assert set(truth["effects"]) == {name}


def test_blind_pair_found_by_the_warming_of_the_cold_neighbours(tmp_path):
    """A supply limit and thermal coupling (gap_blind's own-default seed 1034): coupling alone
    does next to nothing for the tilt (2 % worse; 4 % better since the baseline fits a warm
    spring's thermoelastic tension: it is the supply limit the tilt needs), but the
    springs not yet powered warm as coupling predicts, and the pair of the two is named. (With
    the baseline prior at 0.005 the supply limit alone fell short and the pair came only
    through the neighbours' warming; at 0.0005 the refitted baseline leaves the supply limit
    enough to be responsible alone, and coupling joins it as the second effect. Coupling alone
    is responsible too since a tilt that is not significantly worse no longer vetoes the
    warming.)"""
    ds = tmp_path / "ds"
    generate(ds, ["supply_limit", "thermal_coupling"], seed=1034, baseline="default")
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    single = {e["name"]: e for e in rep["effects"]}
    coupling = single["thermal_coupling"]
    assert -0.1 < coupling["heldout_reduction"] < 0.1  # the tilt alone does not ask for it ...
    w = coupling["heldout_cold_neighbours_T"]
    assert w["F"] > w["F_crit"] and w["warms"]  # ... the neighbours' thermistors do
    assert coupling["significant"]
    assert single["supply_limit"]["significant"]
    # the report says on what: coupling on the warming (not the tilt), the limit on the tilt
    assert "neighbours' warming" in coupling["grounds"] and "tilt" not in coupling["grounds"]
    assert "tilt" in single["supply_limit"]["grounds"]
    assert all(bool(e["grounds"]) == e["significant"] for e in rep["effects"])
    assert sorted(rep["verdict"]) == ["supply_limit", "thermal_coupling"]
    assert rep["corrected"]["heldout_reduction"] > 0.4


def test_a_second_effect_is_not_credited_with_further_fitting(tmp_path):
    """Convection alone (gap_blind's own-default seed 1012). A pair starts from the single's
    fit and is fitted on; judged against the single as first fitted, seven second effects won
    37-46 % of its held-out gap and coupling 25 %. Against the single refitted as long, none
    wins 20 %."""
    from neck_env.gap.diagnose import MIN_REL

    ds = tmp_path / "ds"
    generate(ds, ["convection_change"], seed=1012, baseline="default")
    rep = _diagnose(ds, tmp_path)
    assert rep["verdict"] == ["convection_change"]
    assert len(rep["pairs"]) == len(rep["effects"]) - 1
    assert all(p["heldout_reduction_vs_best_single"] < MIN_REL for p in rep["pairs"]), [
        (p["name"], p["heldout_reduction_vs_best_single"]) for p in rep["pairs"]]
    # the verdict is the refitted single: its held-out gap is the pairs' reference
    assert rep["corrected"]["heldout_gap"] == pytest.approx(
        rep["pairs"][0]["heldout_gap_best_single"], rel=0.02)


def test_what_the_first_effect_leaves_of_a_structural_misfit_is_no_second_effect(tmp_path):
    """Thermal coupling alone on the independent rig (gap_blind's fresh independent seed 5020,
    the springs' modulus fitted). Convection on top of coupling takes about the 20 % margin of
    the single's held-out gap (22 %; 19 % since the baseline fits a warm spring's thermoelastic
    tension), and was named beside it while the pairs' structural rival was a discrepancy on
    the baseline; a generic discrepancy on top of coupling takes about as much (the independent
    rig's structure, not a second effect), so coupling alone is the verdict."""
    from neck_env.gap.diagnose import MIN_REL
    from neck_env.gap.independent import generate as generate_independent

    ds = tmp_path / "ds"
    generate_independent(ds, ["thermal_coupling"], seed=5020, baseline="wide")
    rep = _diagnose(ds, tmp_path, extra=["--fit-spring-modulus"])
    assert rep["verdict"] == ["thermal_coupling"]
    best = rep["pairs"][0]
    assert best["effects"][0] == "thermal_coupling" and not best["significant"]
    assert best["heldout_reduction_vs_best_single"] >= 0.75 * MIN_REL, best
    rival = best["heldout_gap_structure"]
    assert rival < best["heldout_gap_best_single"], best  # the discrepancy takes part of it ...
    assert (rival - best["heldout_gap_after"]) / rival < MIN_REL, best  # ... the pair no 20 % more


# -- bad input: a clear error naming file and line, nothing written --------------------------

GOOD = "t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.02,5,0,0,0.1,180\n0.04,5,0,0,0.2,180\n"


@pytest.mark.parametrize("files, fragment", [
    ({}, "no *.csv recordings in this folder"),
    ({"rec_01.csv": GOOD, "rec_02.csv": "t,i1,i2,theta_deg,phi_deg\n0,0,0,0,0\n"},
     "rec_02.csv, line 1: missing required column(s) i3"),
    ({"rec_01.csv": GOOD.replace("0.04,", "0.02,")}, "rec_01.csv, line 4"),
    # a missing IMU reading is filled over 0.5 s at most: over 0.98 s it is bad input
    ({"rec_01.csv": GOOD.replace("0.1,180", "nan,180").replace("0.04,", "1.0,")},
     "rec_01.csv, line 3: theta_deg/phi_deg missing on line 3 (1 row): the readings around them "
     "are 1 s apart"),
    ({"rec_01.csv": GOOD.replace("0.1,180", "inf,180")}, "rec_01.csv, line 3"),
    ({"rec_01.csv": GOOD, "rec_02.csv": ""}, "rec_02.csv"),
])
def test_bad_input_names_file_and_line_and_writes_nothing(tmp_path, capsys, files, fragment):
    ds = tmp_path / "ds"
    ds.mkdir()
    for name, text in files.items():
        (ds / name).write_text(text)
    out = tmp_path / "out" / "report.json"
    rc = gap_main([str(ds), "--json", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert fragment in err, err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_missing_folder_and_module_entry_point(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "neck_env.gap", str(tmp_path / "nope"),
                           "--json", str(tmp_path / "r.json")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "nope" in proc.stderr
    assert not (tmp_path / "r.json").exists()


def test_synthetic_generator_is_seeded(tmp_path):
    a = generate(tmp_path / "a", ["head_payload"], seed=3)
    b = generate(tmp_path / "b", ["head_payload"], seed=3)
    assert a["effects"] == b["effects"]
    ra, rb = read_dataset(tmp_path / "a"), read_dataset(tmp_path / "b")
    assert len(ra) == len(rb) == 15
    for x, y in zip(ra, rb):
        np.testing.assert_array_equal(x.theta_deg, y.theta_deg)
    p = fx.EFFECTS["head_payload"].params["mass_kg"]
    lo, hi = p.low, p.high
    assert lo <= a["effects"]["head_payload"]["mass_kg"] <= hi


def test_every_effect_nests_the_nominal_model(tmp_path):
    """At its "off" value each fitted effect is exactly the baseline (the nested comparison
    is valid), and away from it each one changes the prediction."""
    from neck_env.gap import model as M

    ds = tmp_path / "small"
    generate(ds, [], seed=4, n_recordings=3, duration_s=12.0, temperatures=True)
    mdl = M.Model(M.prepare(read_dataset(ds)))
    base = {s.key: s.start for s in mdl.nominal}
    nominal = mdl.predict([base])[0]
    for name, specs in M.EFFECT_SPECS.items():
        u = 0.3 if name == "supply_limit" else 0.8  # 40 V, the top of its range, is "off"
        on = dict(base, **{s.key: s.from_unit(u) for s in specs})
        if name == "convection_change":
            on[M.DRAFT_FROM] = 1.0
        off = M.switched_off(on)
        p_off, p_on = mdl.predict([off, on])
        assert np.allclose(p_off.tilt_x, nominal.tilt_x, atol=1e-9), name
        assert np.allclose(p_off.T, nominal.T, atol=1e-9), name
        moved = np.abs(p_on.tilt_x - nominal.tilt_x).max() + np.abs(p_on.T - nominal.T).max()
        assert moved > 1e-3, f"{name} at {u} of its range changes nothing"


def test_thermistor_lag_reads_the_springs_late_and_shares_the_simulation(tmp_path):
    """The baseline's thermistor lag changes only the temperatures the model reads (they trail
    a heating spring), never the tilt, and costs no simulation of its own."""
    from neck_env.gap import model as M

    ds = tmp_path / "small"
    generate(ds, [], seed=4, n_recordings=2, duration_s=12.0, temperatures=True)
    mdl = M.Model(M.prepare(read_dataset(ds)))
    base = {s.key: s.start for s in mdl.nominal}
    assert base["thermistor_lag_s"] == 0.0  # centred on none: our own rig has no lag
    before = mdl.sim_count
    plain, lagged = mdl.predict([base, dict(base, thermistor_lag_s=1.2)])
    assert mdl.sim_count - before == mdl.data.n_rec * mdl.data.n_steps  # one plant run for both
    np.testing.assert_array_equal(plain.tilt_x, lagged.tilt_x)
    heating = np.diff(plain.T[:, 0]) > 0.5  # a spring heating at > 5 C/s (10 Hz samples)
    assert heating.any()
    assert (lagged.T[1:, 0][heating] < plain.T[1:, 0][heating]).all()
    assert np.abs(lagged.T - plain.T).max() > 5.0
    # and the model without thermistors has no lag to fit
    generate(tmp_path / "noT", [], seed=4, n_recordings=2, duration_s=12.0, temperatures=False)
    assert "thermistor_lag_s" not in {s.key for s in
                                      M.Model(M.prepare(read_dataset(tmp_path / "noT"))).nominal}


def _blind_other_rig(tmp_path: Path, generate, wire_d_m: float, effects, seed: int):
    """A rig written apart from the model (``gap_blind.OTHER_RIGS``), diagnosed blind: the model is
    knowingly wrong about its structure, so nothing may be blamed on effect-free data (whose
    cooling tail still gives the rig's time constant, and h for the wire meta.json gives), and
    an effect with a signature no baseline has is still named. Returns (dataset, report)."""
    ds = tmp_path / "ds"
    truth = generate(ds, effects, seed=seed, baseline="wide")
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    if not effects:
        assert rep["verdict"] == []
        # the time constant of a cooling tail is the same physical figure in both models; h
        # follows from it for the wire meta.json gives (its heat capacity per area is not ours)
        tau = rep["calibration"]["cooling_time_constant_s"]
        assert tau["identified"]
        assert abs(tau["value"] / truth["physical"]["cooling_time_constant_s"] - 1) < 0.25
        h = rep["calibration"]["convection_W_m2K"]
        assert h["identified"] and h["wire_diameter_m"] == pytest.approx(wire_d_m)
        assert abs(h["value"] / truth["physical"]["convection_W_m2K"] - 1) < 0.25
    else:
        assert rep["verdict"] == effects
        assert rep["effects"][0]["name"] == effects[0]
    return ds, rep


# The structurally independent rig (neck_env.gap.independent: its own spring arrangement, head
# inertia, exponential kinetics, integrator and Table 1 calibration, baseline drawn wide).
INDEPENDENT = [([], 1000), (["imu_misalignment"], 1002), (["supply_limit"], 1005),
               (["thermal_coupling"], 1011)]


@pytest.mark.parametrize("effects, seed", INDEPENDENT,
                         ids=[e[0] if e else "none" for e, _ in INDEPENDENT])
def test_blind_independent_rig(tmp_path, effects, seed):
    from neck_env.gap import independent

    ds, rep = _blind_other_rig(tmp_path, independent.generate, independent.WIRE_D_M, effects, seed)
    if not effects:
        # h is this rig's, on the wire meta.json gives (0.9 mm, c 550 J/kg K): the model's own
        # h on its 0.8 mm wire differs by their heat capacities per area, times the fitted
        # heat-capacity multiplier (both hold the tail's one time constant)
        h = rep["calibration"]["convection_W_m2K"]
        base = default_params()
        hc = rep["calibration"]["params"]["heat_capacity_scale"]["value"]
        per_area = (base.material.specific_heat_J_kgK * base.spring.wire_diameter_m
                    / (independent.CALIBRATED.c_p_J_kgK * independent.WIRE_D_M))
        assert h["model_h_W_m2K"] == pytest.approx(h["value"] * per_area * hc, rel=0.005), h
        # NeckTrack-v0 loaded from the export is this rig up to the structural misfit (the
        # held-out gap, ~0.3 deg): far closer than the defaults' rig
        exported, defaults = _replay_export_and_defaults(ds, rep)
        assert np.median(exported) < 2 * rep["effects"][0]["heldout_gap_before"], exported
        assert np.sqrt(np.mean(exported ** 2)) < 0.25 * np.sqrt(np.mean(defaults ** 2)), (
            exported, defaults)
    if effects == ["thermal_coupling"]:
        # thermistors recorded: the springs not yet powered warm as the coupled model predicts
        # (this rig's structural misfit leaves the tilt evidence alone short of a verdict)
        assert rep["temperatures_used"]
        w = rep["effects"][0]["heldout_cold_neighbours_T"]
        assert w["warms"] and w["F"] > w["F_crit"], w


def test_a_creep_is_named_where_the_thermistors_deny_the_delay_that_rivalled_it(tmp_path):
    """The independent rig of gap_blind's fresh suite, seed 12517: a backbone creeping with
    tau 1.4 s (stiffness ratio 2.9). Its fit rests at the edge of the catalogue's range, and a
    0.76 s actuation delay inside its own range was significant too, so the creep yielded and
    the delay was named -- while the delay's fit left the springs' held-out temperatures
    0.67 -> 1.14 C. A current that acts late heats the springs late: the thermistors deny the
    delay, and the creep, far beyond the F test (held-out gap 1.165 -> 0.39 deg), is named."""
    from neck_env.gap import independent

    ds = tmp_path / "ds"
    independent.generate(ds, ["backbone_viscoelasticity"], seed=12517, baseline="wide",
                         temperatures=True)
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    assert rep["verdict"] == ["backbone_viscoelasticity"], rep["verdict"]
    delay = next(e for e in rep["effects"] if e["name"] == "actuation_delay")
    assert "further off" in delay["unresolved"], delay["unresolved"]
    assert delay["heldout_T"]["rms_after_C"] > 1.2 * delay["heldout_T"]["rms_before_C"]


def test_a_second_thermal_effect_is_named_on_the_temperatures_its_pair_explains(tmp_path):
    """The independent rig of gap_blind's fresh suite, seed 12535: a thermal coupling
    (0.0087 W/K) and a convection growing 0.0094/K. The coupling is named on the cold
    neighbours' warming; the convection beside it took 20 % of the held-out tilt left by the
    coupling, not consistently enough for the tilt's tests, and the pair was refused -- while
    the springs' held-out temperatures the coupling left (1.86 C) fell to 0.38 C with it. A pair
    adding a thermal effect is judged on the temperatures as a single one is."""
    from neck_env.gap import independent

    ds = tmp_path / "ds"
    independent.generate(ds, ["convection_change", "thermal_coupling"], seed=12535,
                         baseline="wide", temperatures=True)
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    assert sorted(rep["verdict"]) == ["convection_change", "thermal_coupling"], rep["verdict"]
    pair = next(p for p in rep["pairs"] if set(p["effects"]) == set(rep["verdict"]))
    assert pair["significant"] and pair["heldout_T"]["fits"], pair
    assert pair["heldout_T"]["rms_after_C"] < 0.5 * pair["heldout_T"]["rms_before_C"], pair
    # the pairs built on the coupling carry the comparison exactly where they add a thermal effect
    for p in rep["pairs"]:
        added = [n for n in p["effects"] if n != "thermal_coupling"]
        assert ("heldout_T" in p) == any(fx.EFFECTS[n].thermal for n in added), p["name"]


def test_two_effects_each_too_weak_alone_are_named_as_the_pair(tmp_path):
    """The independent rig of gap_blind's fresh suite, seed 13036: an actuation delay (0.32 s)
    and a backbone friction (0.044 N m). Alone each falls short of the F test (the friction
    took 21 % of the held-out gap, F 1.60 against 1.63; the delay 14 %), and the gap they leave
    together was under the `unexplained` line, so no pair used to be tried. As a pair they
    take 0.48 -> 0.28 deg, beating either alone: named."""
    from neck_env.gap import independent

    ds = tmp_path / "ds"
    independent.generate(ds, ["actuation_delay", "backbone_friction"], seed=13036,
                         baseline="wide", temperatures=True)
    rep = _diagnose(ds, tmp_path)
    _check_contract(rep)
    assert not any(e["significant"] for e in rep["effects"])  # neither alone
    assert sorted(rep["verdict"]) == ["actuation_delay", "backbone_friction"], rep["verdict"]
    pair = next(p for p in rep["pairs"] if set(p["name"].split("+")) == set(rep["verdict"]))
    assert pair["significant"]
    assert pair["heldout_gap_after"] < 0.8 * pair["heldout_gap_best_single"], pair


# The third rig (neck_env.gap.third), written apart from this model and the independent rig:
# rigid segments on joints, two springs in series per muscle, its own kinetics law, a second
# thermal node and a Mahony-fused IMU. Seeds of gap_blind's third suite: an effect-free rig whose
# best wrong effect takes 2-3 % of the gap, and a supply limit that takes ~74 %.
THIRD = [([], 1001), (["supply_limit"], 1018)]


@pytest.mark.parametrize("effects, seed", THIRD, ids=[e[0] if e else "none" for e, _ in THIRD])
def test_blind_third_rig(tmp_path, effects, seed):
    from neck_env.gap import third

    _blind_other_rig(tmp_path, third.generate, third.WIRE_D_M, effects, seed)


def test_a_neck_that_never_moved_is_told_from_its_thermistors_or_not_at_all(tmp_path):
    """The third rig of gap_blind's fresh suite, seed 6027: a supply that cannot drive the
    springs on a fast-cooling rig, and the neck moves 0.25 deg. Judged on its tilt, which is
    noise, ``backbone_friction`` was named; the springs' temperatures show the supply limit.
    Without thermistors nothing can be named, and the report says why."""
    from neck_env.gap import third

    limit = {"supply_limit": {"compliance_V": 3.425, "wiring_ohm": 0.164}}
    third.generate(tmp_path / "T", limit, seed=6027, baseline="wide", temperatures=True)
    rep = _diagnose(tmp_path / "T", tmp_path, "T")
    _check_contract(rep)
    act = rep["actuation"]
    assert not act["actuated"] and act["moved_deg"] < act["threshold_deg"]
    assert "backbone_friction" not in act["nameable"]
    assert rep["verdict"] == ["supply_limit"]
    third.generate(tmp_path / "noT", limit, seed=6027, baseline="wide", temperatures=False)
    rep = _diagnose(tmp_path / "noT", tmp_path, "noT")
    assert rep["actuation"]["nameable"] == []
    assert rep["verdict"] == [] and rep["unexplained"]
    assert any("did not actuate" in r for r in rep["unexplained_reasons"])


def test_the_springs_temperatures_name_a_convection_the_tilt_leaves_to_friction(tmp_path):
    """The third rig of gap_blind's fresh suite, seed 6030: a convection coefficient that grows
    with the spring's temperature. On the tilt, friction fits as well and a structural
    discrepancy comes within the margin (friction was named); the held-out thermistors, which
    friction leaves as the nominal refit did, the convection explains."""
    from neck_env.gap import third

    third.generate(tmp_path / "ds", ["convection_change"], seed=6030, baseline="wide",
                   temperatures=True)
    rep = _diagnose(tmp_path / "ds", tmp_path)
    _check_contract(rep)
    assert rep["verdict"] == ["convection_change"]
    conv = {e["name"]: e for e in rep["effects"]}["convection_change"]
    assert conv["heldout_T"]["fits"] and conv["heldout_T"]["reduction"] > 0.4
    # friction changes no temperature: it is not compared on them
    assert "heldout_T" not in {e["name"]: e for e in rep["effects"]}["backbone_friction"]


def test_springs_in_still_air_are_a_rival_on_request_and_a_growth_named_without_says_so(tmp_path):
    """An effect-free independent rig whose springs' h follows free convection (h ~ dT^0.25,
    ``gap_blind.py --convection natural --effect-free``, seed 11923): a linear growth of h fits
    it (0.0058/K, 46 % of the held-out tilt gap) and, against constant-h rivals only, is named;
    its entry says still air explains it as well. With ``--still-air`` free convection is the
    rival it matches: nothing is named, the growth is listed ``ambiguous`` with it, and the
    export carries still air."""
    from neck_env.gap import independent

    truth = independent.generate(tmp_path / "ds", [], seed=11923, baseline="wide",
                                 temperatures=True, convection="natural")
    assert truth["baseline"]["h_exponent"] == 0.25 and truth["effects"] == {}

    rep = _diagnose(tmp_path / "ds", tmp_path, "plain")
    _check_contract(rep)
    assert rep["verdict"] == ["convection_change"]
    conv = rep["effects"][0]
    still = conv["still_air"]
    # still air does as well as the growth, and far better than a constant h
    assert still["heldout_gap_still_air"] < 0.8 * conv["heldout_gap_before"], still
    assert abs(still["heldout_gap_still_air"] - conv["heldout_gap_after"]) < 0.1 * conv["heldout_gap_before"]
    assert "--still-air" in still["note"] and "cooling tail" in still["note"]
    assert "still_air" not in {s["name"] for s in rep["structure"]}

    rep = _diagnose(tmp_path / "ds", tmp_path, "still", ["--still-air"])
    _check_contract(rep)
    assert rep["verdict"] == []
    best = max(rep["structure"], key=lambda s: s["heldout_reduction"])
    assert best["name"] == "still_air" and best["heldout_reduction"] > 0.3, rep["structure"]
    assert 0.15 <= best["params"]["h_exponent"] <= 1 / 3 + 1e-9
    conv = {e["name"]: e for e in rep["effects"]}["convection_change"]
    assert conv["significant_vs_nominal"] and not conv["significant"] and "still_air" not in conv
    (a,) = [a for a in rep["ambiguous"] if a["effect"] == "convection_change"]
    assert a["with"] == ["h_exponent"] and "cooling tail" in a["note"], a
    assert a["heldout_gap_with"] == pytest.approx(best["heldout_gap_after"], abs=2e-4)
    # still air is no effect, but the rig's structure: the export carries it, so NeckTrack-v0
    # built from it cools as this rig does, on recordings the diagnosis never saw (the same
    # rig, another lab's pulse timing)
    x = rep["export"]
    assert x["structure"] == "still_air" and x["exported"], x
    assert x["gap_all_recordings_with_deg"] < x["gap_all_recordings_without_deg"], x
    n = NeckParams.load(rep["outputs"]["params"]).thermal.convection_exponent
    assert n == pytest.approx(x["params"]["h_exponent"], abs=1e-6) and 0.15 <= n <= 1 / 3 + 1e-9
    independent.generate(tmp_path / "unseen", [], seed=11923, baseline="wide", protocol="drawn",
                         temperatures=True, convection="natural", n_recordings=4)
    exported, defaults = _replay_export_and_defaults(tmp_path / "unseen", rep)
    assert np.median(exported) < 2 * best["heldout_gap_after"], (exported, best)
    assert np.sqrt(np.mean(exported ** 2)) < 0.25 * np.sqrt(np.mean(defaults ** 2)), (
        exported, defaults)


# Dataset shapes the blind suites never use (a small faithful version of
# benchmarks/gap_shapes.py): another IMU rate, four recordings, no meta.json, another lab's
# pulse timing. ``named``: four recordings hold one out, and since the baseline fits a warm
# spring's thermoelastic tension (2026-11-30) the draft there is ranked first but not named.
@pytest.mark.parametrize("shape, effect, named", [("hz100", "imu_misalignment", True),
                                                  ("nometa", "actuation_delay", True),
                                                  ("rec4x30", "convection_change", False),
                                                  ("drawn", "actuation_delay", True)])
def test_unseen_dataset_shapes(tmp_path, gap_shapes_script, shape, effect, named):
    gs = gap_shapes_script
    r = gs.run(shape, effect, gs.seed_of(effect), tmp_path)
    assert r["rc"] == 0
    assert r["top"][0] == effect, r
    if named:
        assert effect in r["verdict"], r


def test_an_unknown_ambient_is_scanned_with_the_baseline(tmp_path, gap_shapes_script):
    # No meta.json and no thermistors: the room is assumed at 25 +- 4 C. Independent rig
    # 13302 (wide baseline, 31.9 C, a 0.91 s delay): with the ambient left out of the global
    # scan the baseline settled at the 35 C bound with the transformation temperatures off to
    # match, and the delay fitted from there took 0.39 s and 22 % of the gap (not named)
    gs = gap_shapes_script
    r = gs.run("nometa", "actuation_delay", 13302, tmp_path)
    rep = json.loads((tmp_path / "nometa_actuation_delay_13302_report.json").read_text())
    truth = json.loads((tmp_path / "nometa_actuation_delay_13302.truth.json").read_text())
    assert rep["ambient"]["source"].startswith("assumed"), rep["ambient"]
    assert r["verdict"] == ["actuation_delay"], r
    amb = rep["calibration"]["params"]["ambient_C"]["value"]
    assert amb == pytest.approx(truth["baseline"]["ambient_C"], abs=2.0)
    delay = rep["effects"][0]["params"]["delay_s"]
    assert delay == pytest.approx(truth["effects"]["actuation_delay"]["delay_s"], abs=0.1)


def test_a_strong_coupling_is_fitted_from_its_split_of_the_baseline_h(tmp_path):
    """Own wide rig 13207 of ``gap_blind.py --baseline wide --quick --first-seed 13200``: a
    coupling of 0.018 W/K (more than a spring's own h A) on a rig cooling in 45 s, no
    thermistors. The baseline refitted without it settles at h x1.5 (x0.56 true), every strong
    coupling scanned on top of that scans worst, and the coupling fitted from the best scan
    point took 0.005 W/K and nothing of a 1.15 deg held-out gap (no verdict). Started from the
    split of h (``diagnose._coupling_rebalanced``) it is named at its size."""
    truth = generate(tmp_path / "ds", ["thermal_coupling"], seed=13207, baseline="wide")
    assert not truth["temperatures"]
    rep = _diagnose(tmp_path / "ds", tmp_path)
    assert rep["verdict"] == ["thermal_coupling"], rep["verdict"]
    coupling = {e["name"]: e for e in rep["effects"]}["thermal_coupling"]
    true_g = truth["effects"]["thermal_coupling"]["conductance_W_K"]
    assert coupling["params"]["conductance_W_K"] == pytest.approx(true_g, rel=0.3)
    assert coupling["heldout_gap_before"] > 1.0 and coupling["heldout_reduction"] > 0.8


def test_gap_blind_resumes_an_interrupted_run_and_refuses_another_suites_folder(
        tmp_path, capsys, gap_blind_script):
    gb = gap_blind_script
    tiny = ["--datasets", "2", "--recordings", "3", "--duration", "10", "--out", str(tmp_path)]
    assert gb.main(tiny) == 0
    first = json.loads((tmp_path / "results.json").read_text())
    assert [r["seed"] for r in first] == [1000, 1001]
    # interrupted after the first dataset: only the second runs again
    (tmp_path / "result_1001.json").unlink()
    report_1000 = (tmp_path / "report_1000.json").stat().st_mtime_ns
    capsys.readouterr()
    assert gb.main(tiny + ["--resume"]) == 0
    out = capsys.readouterr().out
    assert "resuming: 1 dataset(s) already diagnosed" in out and "1 to run" in out
    assert (tmp_path / "report_1000.json").stat().st_mtime_ns == report_1000
    again = json.loads((tmp_path / "results.json").read_text())
    assert [r["seed"] for r in again] == [1000, 1001]
    assert again[1]["report"]["verdict"] == first[1]["report"]["verdict"]
    # the same folder with another suite's options: refused, nothing overwritten
    with pytest.raises(SystemExit, match="resume with the same options"):
        gb.main(tiny + ["--resume", "--baseline", "wide"])
    with pytest.raises(SystemExit, match="resume with the same options"):  # a fresh suite's seeds
        gb.main(tiny + ["--resume", "--first-seed", "5000"])
    assert (tmp_path / "report_1000.json").stat().st_mtime_ns == report_1000


def test_gap_blind_effect_size_is_what_the_effect_moves_in_the_data(tmp_path, gap_blind_script):
    """The benchmark's effect size: the RMS tilt-vector difference (over sqrt 2) between a
    dataset and its twin with the effects off (same rig, protocol and noise). An IMU mount
    tilted by 3 deg (no yaw) offsets every reading by about 3 deg, so 3 / sqrt 2 = 2.12 deg on
    either generator -- a twin with other noise or another protocol would be far off; nothing
    switched on, nothing moves."""
    from neck_env.gap.independent import generate as generate_independent

    gb = gap_blind_script
    kw = dict(baseline="wide", n_recordings=2, duration_s=10.0)
    tilted = {"imu_misalignment": {"yaw_deg": 0.0, "tilt_deg": 3.0, "tilt_dir_deg": 40.0}}
    generate_independent(tmp_path / "mis", tilted, seed=11, **kw)
    size = gb.effect_size_deg(tmp_path / "mis", tilted, 11, "independent", **kw)
    assert 2.0 < size < 2.25, size
    generate(tmp_path / "own", tilted, seed=11, **kw)
    size = gb.effect_size_deg(tmp_path / "own", tilted, 11, "synthetic", **kw)
    assert 2.0 < size < 2.25, size
    twin = generate(tmp_path / "off", tilted, seed=11, switched_off=True, **kw)
    assert twin["effects"] == {} and "imu_misalignment" in twin["drawn_effects_switched_off"]
    generate_independent(tmp_path / "free", [], seed=11, **kw)
    assert gb.effect_size_deg(tmp_path / "free", [], 11, "independent", **kw) == 0.0


def test_gap_blind_protocol_reaches_the_dataset_and_its_twin(tmp_path, gap_blind_script):
    """``--protocol`` draws every dataset (and the twin its effect size is measured against)
    with that protocol, and a resume with another protocol is refused."""
    gb = gap_blind_script
    tiny = ["--recordings", "3", "--duration", "10", "--out", str(tmp_path)]
    assert gb.main(tiny + ["--protocol", "paper", "--only", "1006"]) == 0
    truth = json.loads((tmp_path / "ds_1006.truth.json").read_text())
    assert truth["protocol"] == "paper"
    assert all(r["protocol"].startswith("pulse ") for r in truth["recordings"])
    (r,) = json.loads((tmp_path / "results.json").read_text())
    # measured against a twin of the same paper-protocol dataset with the effect off
    effects = truth["effects"]
    assert r["effect_size_deg"] == pytest.approx(gb.effect_size_deg(
        tmp_path / "ds_1006", effects, 1006, "synthetic", protocol="paper", n_recordings=3,
        duration_s=10.0))
    assert r["effect_size_deg"] != pytest.approx(gb.effect_size_deg(
        tmp_path / "ds_1006", effects, 1006, "synthetic", n_recordings=3, duration_s=10.0))
    with pytest.raises(SystemExit, match="resume with the same options"):
        gb.main(tiny + ["--protocol", "rig", "--only", "1006", "--resume"])


def test_gap_blind_logging_options_reach_the_dataset(tmp_path, gap_blind_script):
    """``--sample-hz`` sets the rigs' logging rate and ``--no-meta`` leaves meta.json out (the
    diagnosis then takes the rate from the time stamps and the room from the data); a resume
    with meta.json is another suite."""
    gb = gap_blind_script
    tiny = ["--recordings", "3", "--duration", "10", "--out", str(tmp_path), "--only", "1000"]
    assert gb.main(tiny + ["--sample-hz", "25", "--no-meta"]) == 0
    ds = tmp_path / "ds_1000"
    assert not (ds / "meta.json").exists()
    rec = read_dataset(ds).recordings[0]
    assert np.median(np.diff(rec.t)) == pytest.approx(1 / 25)
    rep = json.loads((tmp_path / "report_1000.json").read_text())
    assert rep["ambient"]["source"] != "meta.json"
    with pytest.raises(SystemExit, match="resume with the same options"):
        gb.main(tiny + ["--sample-hz", "25", "--resume"])


def test_gap_blind_first_seed_draws_a_fresh_suite_of_the_same_mix(gap_blind_script):
    gb = gap_blind_script
    for quick in (False, True):
        base, fresh = gb.cases(quick), gb.cases(quick, first_seed=5000)
        assert [e for e, _ in fresh] == [e for e, _ in base]
        assert [s for _, s in base] == list(range(1000, 1000 + len(base)))
        assert [s for _, s in fresh] == list(range(5000, 5000 + len(base)))
    free = gb.cases(False, first_seed=7000, effect_free=30)
    assert free == [([], s) for s in range(7000, 7030)]
    with pytest.raises(ValueError, match="at least 1"):
        gb.cases(False, effect_free=0)


def test_gap_blind_rates_carry_their_exact_interval(gap_blind_script):
    """Clopper-Pearson bounds: 0/6 reaches 46 % (one-sided 2.5 % tail: 1 - 0.025^(1/6)); 1/6
    of effect-free rigs cannot show a 10 % target missed; 27/27 still leaves 87 %."""
    gb = gap_blind_script
    assert gb.rate(0, 6) == "0/6 = 0 % [95 % CI 0-46 %]"
    assert gb.rate(1, 6) == "1/6 = 17 % [95 % CI 0-64 %]"
    assert gb.rate(27, 27) == "27/27 = 100 % [95 % CI 87-100 %]"
    assert gb.rate(0, 0) == "0/0"


def test_gap_blind_pools_finished_runs_and_refuses_a_rerun_as_a_second_sample(
        tmp_path, gap_blind_script, capsys):
    gb = gap_blind_script

    def folder(name, seeds, verdicts):
        d = tmp_path / name
        d.mkdir()
        (d / "suite.json").write_text(json.dumps({"generator": "independent"}))
        for s, v in zip(seeds, verdicts):
            (d / f"result_{s}.json").write_text(json.dumps(
                {"seed": s, "truth": {}, "rc": 0, "seconds": 1.0, "report": {"verdict": v}}))
        return d

    a = folder("a", [1000, 1001], [[], ["backbone_friction"]])
    b = folder("b", [5000, 5001, 5002], [[], [], []])
    assert gb.main(["--summarize", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "5 datasets (5 effect-free" in out
    assert "false positives 1/5 = 20 % [95 % CI 1-72 %]" in out and "1001: ['backbone_friction']" in out
    with pytest.raises(SystemExit, match="seed 1000 of the independent generator"):
        gb.main(["--summarize", str(a), str(folder("again", [1000], [[]]))])
    with pytest.raises(SystemExit, match="no result_"):
        gb.main(["--summarize", str(tmp_path / "empty")])


def test_gap_blind_counts_verdicts_naming_an_effect_the_rig_lacks(tmp_path, gap_blind_script,
                                                                   capsys):
    """A verdict with the true effect *and* one absent is wrong, as is a drift blamed on an
    effect; a verdict that misses the pair's second effect is not (it names nothing absent)."""
    gb = gap_blind_script
    cases = [(1006, {"head_payload": {}}, ["supply_limit"]),
             (1007, {"supply_limit": {}}, ["supply_limit", "thermal_coupling"]),
             (1008, {"imu_misalignment": {}}, ["imu_misalignment"]),
             (1033, {"actuation_delay": {}, "backbone_friction": {}}, ["actuation_delay"]),
             (1039, {"gyro_bias_drift": {"drift_dps_per_s": 0.01}}, ["backbone_friction"]),
             (1000, {}, [])]
    for seed, truth, verdict in cases:
        (tmp_path / f"result_{seed}.json").write_text(json.dumps(
            {"seed": seed, "truth": truth, "rc": 0, "seconds": 1.0,
             "report": {"verdict": verdict, "corrected": {"heldout_reduction": 0.0}}}))
    (tmp_path / "suite.json").write_text(json.dumps({"generator": "independent"}))
    assert gb.main(["--summarize", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert ("verdict also names one absent: 3/5 [1006 head_payload: supply_limit, "
            "1007 supply_limit: thermal_coupling, 1039 gyro_bias_drift: backbone_friction]") in out


def test_gap_blind_compares_two_runs_dataset_by_dataset(tmp_path, gap_blind_script, capsys):
    """Paired: the McNemar test counts only the datasets one run gets right and the other not
    (here 5 to 0: p = 2 x 0.5^5 = 0.0625), every changed outcome is listed, and runs of other
    datasets are refused."""
    gb = gap_blind_script

    def run(name, named, truth="head_payload"):
        d = tmp_path / name
        d.mkdir()
        for s in range(1000, 1008):
            first = truth if s - 1000 < named else "backbone_friction"
            rep = {"verdict": [first], "effects": [{"name": first}]}
            (d / f"result_{s}.json").write_text(json.dumps(
                {"seed": s, "truth": {truth: {}}, "rc": 0, "seconds": 1.0, "report": rep}))
        return str(d)

    assert gb.main(["--compare", run("a", 1), run("b", 6)]) == 0
    out = capsys.readouterr().out
    assert "single: right in the first 1/8, in the second 6/8; only the first 0, only the second 5 " \
           "(exact McNemar p = 0.062)" in out
    assert "seed 1005 ['head_payload']: missed (first backbone_friction, verdict " \
           "['backbone_friction']) -> named" in out and "seed 1000" not in out
    with pytest.raises(SystemExit, match="not the same datasets"):
        gb.main(["--compare", run("c", 1), run("d", 1, truth="sma_fatigue")])


def test_only_heat_from_a_neighbour_warms_a_spring_not_yet_powered(tmp_path):
    """The cold neighbours (a muscle not yet powered in its recording while another has been)
    are where thermal coupling has a signature no baseline shift has: with coupling in the
    data the coupled model's thermistor residual there falls far below the nominal one's,
    while a larger convection coefficient or constant thermistor offsets give no such warming."""
    from neck_env.gap import diagnose as D
    from neck_env.gap import model as M

    ds = tmp_path / "small"
    generate(ds, [], seed=4, n_recordings=4, duration_s=15.0, temperatures=True)
    data = M.prepare(read_dataset(ds))
    mdl = M.Model(data)
    base = {s.key: s.start for s in mdl.nominal}
    nominal, coupled, draughty = mdl.predict([
        base, dict(base, **{"thermal_coupling.conductance_W_K": 0.01}), dict(base, h_scale=2.0)])
    cold = data.cold_neighbours
    assert cold.any() and not cold.all()
    for r, rows in enumerate(data.rec_slices()):  # never a muscle once it has been powered
        powered = np.maximum.accumulate(data.cmd[r] > 0, axis=0)[data.fit_idx[rows]]
        assert not (cold[rows] & powered).any()
    # the model's own muscles are thermally apart: a cold neighbour stays at ambient
    assert np.allclose(nominal.T[cold], base["ambient_C"], atol=0.05)
    assert (coupled.T[cold] - base["ambient_C"]).max() > 1.0
    everywhere = np.ones(data.fit_rec.size, bool)
    noise = np.random.default_rng(0).normal(0.0, 0.5, data.meas_T.shape)
    data.meas_T = coupled.T + noise  # a rig with coupling
    w = D.warming_compare(data, nominal, coupled, everywhere)
    assert w.F > w.F_crit and w.reduction > 0.5, w
    assert D.warming_compare(data, nominal, draughty, everywhere).reduction <= 0.0
    # a rig without coupling whose thermistors read 0.4 C off: the coupled model is worse
    data.meas_T = nominal.T + noise + np.array([0.4, -0.4, 0.4])
    assert D.warming_compare(data, nominal, coupled, everywhere).reduction < 0.0


def test_gap_blind_checks_the_reported_h_and_time_constant_against_the_truth(
        tmp_path, gap_blind_script, capsys):
    """Effect-free rigs: the fitted h and cooling time constant against the generator's
    physical truth, within +-25 % and within the reported +-2 std (is the std honest?)."""
    cases = [(1000, (110.0, 8.0), (9.0, 0.2)),  # h +10 %, 1.25 std: held; tau -10 %, 5 std: not
             (1001, (70.0, 5.0), (10.5, 0.5))]  # h -30 %, 6 std: neither; tau +5 %, 1 std
    for seed, h, tau in cases:
        cal = {"convection_W_m2K": {"value": h[0], "std": h[1], "identified": True},
               "cooling_time_constant_s": {"value": tau[0], "std": tau[1], "identified": True}}
        (tmp_path / f"result_{seed}.json").write_text(json.dumps(
            {"seed": seed, "truth": {}, "rc": 0, "seconds": 1.0,
             "physical_truth": {"convection_W_m2K": 100.0, "cooling_time_constant_s": 10.0},
             "report": {"verdict": [], "calibration": cal}}))
    (tmp_path / "suite.json").write_text(json.dumps({"generator": "independent"}))
    assert gap_blind_script.main(["--summarize", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert ("h (W/m^2K) fitted / true - 1 = +10 %, -30 %; within +-25 %: 1/2; "
            "truth within the reported +-2 std: 1/2") in out
    assert ("m c/(h A) fitted / true - 1 = -10 %, +5 %; within +-25 %: 2/2; "
            "truth within the reported +-2 std: 1/2") in out
