"""The structurally independent "real rig" generator (``neck_env.gap.independent``): its own
calibration to the paper's Table 1, the recording format, the truth beside the folder, what each
effect changes (and that nothing changes without one), and that it shares no physics code with
the project's model."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

from neck_env.gap import independent as ind
from neck_env.recording import REQUIRED_COLUMNS, TEMPERATURE_COLUMNS, read_dataset

FORBIDDEN = ("neck_env.physics", "neck_env.params", "neck_env.calibration", "neck_env.sensors",
             "neck_env.observation", "neck_env.gap.model", "neck_env.gap.synthetic")

# Table 1 tolerance: the paper's own numbers disagree with each other (13.9 deg at 5 A in its
# discussion, 5.89 deg in the table), so a structurally different model is held to a few degrees.
TABLE1_MAX_ERR_DEG = 3.5
TABLE1_RMS_DEG = 2.5


def _pulse_cmd(amps: float, hz: float = 50.0, dur: float = 14.0, muscle: int = 0):
    t = np.arange(int(dur * hz) + 1) / hz
    cmd = np.zeros((t.size, 3))
    cmd[(t >= 2.0 - 1e-9) & (t < 7.0 - 1e-9), muscle] = amps
    return t, cmd


def _small(tmp_path: Path, name: str, effects=None, seed: int = 4, **kw) -> tuple[Path, dict]:
    kw.setdefault("protocol", "paper")
    kw.setdefault("n_recordings", 6)
    kw.setdefault("duration_s", 16.0)
    out = tmp_path / name
    return out, ind.generate(out, effects, seed=seed, **kw)


def _large_tilt_phi(rec, min_theta: float = 8.0) -> float:
    sel = rec.theta_deg > min_theta
    assert sel.sum() > 20, "the recording never bends far enough to read phi"
    ang = np.radians(rec.phi_deg[sel])
    return float(np.degrees(np.arctan2(np.sin(ang).mean(), np.cos(ang).mean())) % 360)


def _wrap(d: float) -> float:
    return (d + 180.0) % 360.0 - 180.0


def test_module_does_not_import_the_projects_physics():
    src = Path(ind.__file__).read_text()
    mods = []
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Import):
            mods += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against neck_env.gap
                pkg = "neck_env.gap".split(".")[: 3 - node.level]
                base = ".".join(pkg + ([base] if base else []))
            mods.append(base)
            mods += [f"{base}.{a.name}" for a in node.names]
    bad = [m for m in mods if any(m == f or m.startswith(f + ".") for f in FORBIDDEN)]
    assert not bad, f"independent.py imports the project's model: {bad}"
    assert "neck_env.experiments" in mods  # sanity: the walk does see its real imports


def test_calibration_reproduces_table1():
    rows = ind.table1()
    err = np.array([m - p for _, m, p in rows])
    assert np.max(np.abs(err)) < TABLE1_MAX_ERR_DEG, rows
    assert np.sqrt(np.mean(err ** 2)) < TABLE1_RMS_DEG, rows
    # monotone in the current, like the paper
    assert all(b[1] > a[1] for a, b in zip(rows, rows[1:])), rows
    # the stored table is what the stored constants give
    assert len(ind.CALIBRATION_TABLE) == 5
    for (a, m, _), (a2, m2, _) in zip(rows, ind.CALIBRATION_TABLE):
        assert a == a2 and abs(m - m2) < 0.05


def test_dataset_format_and_truth_beside_the_folder(tmp_path):
    out, truth = _small(tmp_path, "ds", ["imu_misalignment", "gyro_bias_drift"], protocol="mixed",
                        n_recordings=5, duration_s=12.0, temperatures=True)
    ds = read_dataset(out)
    assert len(ds) == 5 and ds.has_temperatures
    for rec in ds:
        assert set(REQUIRED_COLUMNS) | set(TEMPERATURE_COLUMNS) <= set(rec.columns())
        assert rec.n == 601 and np.all((rec.phi_deg >= 0) & (rec.phi_deg < 360))
    assert set(ds.meta) >= {"ambient_C", "sample_hz", "muscle_azimuth_deg"}
    assert ds.meta["muscle_azimuth_deg"] == [180.0, 60.0, 300.0]
    assert abs(ds.meta["ambient_C"] - truth["baseline"]["ambient_C"]) <= 0.3 + 1e-9
    tp = tmp_path / "ds.truth.json"
    assert tp.exists()
    assert [p.name for p in out.iterdir() if p.suffix == ".json"] == ["meta.json"]
    on_disk = json.loads(tp.read_text())
    assert on_disk["generator"] == "neck_env.gap.independent"
    assert on_disk["effect_names"] == ["gyro_bias_drift", "imu_misalignment"]
    assert on_disk["catalogued"] == ["imu_misalignment"]
    assert abs(on_disk["effects"]["imu_misalignment"]["yaw_deg"]) >= 4.0
    b = on_disk["baseline"]
    assert {"convection_W_m2K", "cooling_time_constant_s", "ratios"} <= set(b)
    assert 0.3 <= b["ratios"]["h_ratio"] <= 4.0
    assert [r["file"] for r in on_disk["recordings"]] == [f"rec_0{k}.csv" for k in range(1, 6)]
    ds2 = read_dataset(_small(tmp_path, "none", None, temperatures=False)[0])
    assert not ds2.has_temperatures


def test_same_seed_without_effects_is_reproducible_and_reads_the_true_azimuth(tmp_path):
    a, ta = _small(tmp_path, "a", baseline="default")
    b, _ = _small(tmp_path, "b", baseline="default")
    ra, rb = read_dataset(a), read_dataset(b)
    for x, y in zip(ra, rb):
        assert np.array_equal(x.theta_deg, y.theta_deg) and np.array_equal(x.phi_deg, y.phi_deg)
    for rec, info in zip(ra, ta["recordings"]):
        assert rec.theta_deg[:50].max() < 2.5  # at rest before the pulse: upright
        if rec.theta_deg.max() > 12:
            muscle = int(info["protocol"].split()[1][1]) - 1
            az = ind.MUSCLE_AZIMUTH_DEG[muscle]
            assert abs(_wrap(_large_tilt_phi(rec) - az)) < 3.0


def test_imu_yaw_rotates_phi_and_nothing_else(tmp_path):
    a, _ = _small(tmp_path, "none", baseline="default")
    b, _ = _small(tmp_path, "yaw", {"imu_misalignment": {"yaw_deg": 12.0, "tilt_deg": 0.3}},
                  baseline="default")
    checked = 0
    for x, y in zip(read_dataset(a), read_dataset(b)):
        if x.theta_deg.max() > 12:
            d = _wrap(_large_tilt_phi(y) - _large_tilt_phi(x))
            assert abs(d + 12.0) < 1.5, d  # phi reads phi_true - yaw
            assert abs(x.theta_deg.max() - y.theta_deg.max()) < 1.0
            checked += 1
    assert checked >= 2


def test_actuation_delay_shifts_the_onset():
    t, cmd = _pulse_cmd(7.0)
    base = ind.simulate_recording(ind.CALIBRATED, cmd)
    late = ind.simulate_recording(ind.CALIBRATED, cmd, effects={"actuation_delay": {"delay_s": 0.6}})
    on = lambda r: t[np.argmax(r["T_C"][:, 0] > ind.CALIBRATED.ambient_C + 5)]  # noqa: E731
    up = lambda r: t[np.argmax(r["theta_deg"] > 5.0)]  # noqa: E731
    assert abs(on(late) - on(base) - 0.6) < 0.05
    assert abs(up(late) - up(base) - 0.6) < 0.1
    assert abs(late["theta_deg"].max() - base["theta_deg"].max()) < 0.5


def test_supply_limit_caps_the_top_currents_only():
    rng = np.random.default_rng(0)
    fx = ind._draw_effect("supply_limit", rng, ind.CALIBRATED, 15)
    peak = {}
    for amps in (4.0, 6.5, 8.0):
        _, cmd = _pulse_cmd(amps)
        free = ind.simulate_recording(ind.CALIBRATED, cmd)
        lim = ind.simulate_recording(ind.CALIBRATED, cmd, effects={"supply_limit": fx})
        peak[amps] = (free["theta_deg"].max(), lim["theta_deg"].max(), lim["I_A"][:, 0].max())
    assert abs(peak[4.0][1] - peak[4.0][0]) < 0.05 and peak[4.0][2] == pytest.approx(4.0)
    assert peak[8.0][2] < 6.5 and peak[6.5][2] < 6.5
    # without the limit 8 A bends far more than 6.5 A; with it they are close
    assert peak[8.0][0] - peak[6.5][0] > 5.0
    assert abs(peak[8.0][1] - peak[6.5][1]) < 0.25 * (peak[8.0][0] - peak[6.5][0])


def test_convection_draft_changes_only_later_recordings(tmp_path):
    draft = {"convection_change": {"mode": "draft", "gain": 2.4, "from_recording_index": 3}}
    a, _ = _small(tmp_path, "none", temperatures=True)
    b, tb = _small(tmp_path, "draft", draft, temperatures=True)
    assert [r["h_multiplier"] for r in tb["recordings"]] == [1, 1, 1, 2.4, 2.4, 2.4]
    ra, rb = read_dataset(a), read_dataset(b)
    for k in range(3):
        assert np.array_equal(ra.recordings[k].temperatures_C, rb.recordings[k].temperatures_C)
    for k in range(3, 6):
        # at the end of the cooling tail the powered spring is much closer to ambient
        amb = ra.meta["ambient_C"]
        ex_a = ra.recordings[k].temperatures_C[-25:].max(axis=1).mean() - amb
        ex_b = rb.recordings[k].temperatures_C[-25:].max(axis=1).mean() - amb
        assert ex_b < 0.6 * ex_a, (k, ex_a, ex_b)


def test_temperature_dependent_convection_cools_hot_springs_faster():
    t, cmd = _pulse_cmd(7.0, dur=30.0)
    base = ind.simulate_recording(ind.CALIBRATED, cmd)
    tdep = ind.simulate_recording(ind.CALIBRATED, cmd, effects={
        "convection_change": {"mode": "tcoef", "tcoef_per_K": 0.01}})
    amb = ind.CALIBRATED.ambient_C
    assert tdep["T_C"][:, 0].max() < base["T_C"][:, 0].max() - 3  # more loss when hot
    late = t > 25
    assert np.all(tdep["T_C"][late, 0] - amb < base["T_C"][late, 0] - amb)


@pytest.mark.parametrize("law", ["natural", "thin_wire"])
def test_free_convection_cools_a_spring_as_a_power_of_its_excess_temperature(law):
    # free convection: h ~ dT^n, so a spring's cooling rate -d ln(dT)/dt grows by 2^n (1.19
    # laminar, 1.11 about a thin wire) from 40 K to 80 K above ambient, where a constant h keeps
    # it (no phase change between: austenite until M_s)
    t = np.arange(40 * 50) / 50.0
    cmd = np.zeros((t.size, 3))
    cmd[(t >= 1.0) & (t < 6.0), 0] = 7.0
    amb = ind.CALIBRATED.ambient_C

    def rates(law):
        p = ind.replace(ind.CALIBRATED, h_exponent=ind.CONVECTION_LAWS[law])
        dT = ind.simulate_recording(p, cmd)["T_C"][:, 0] - amb
        cooling = t > 6.5
        lam = -np.gradient(np.log(np.clip(dT, 1e-3, None)), t)
        return [lam[np.flatnonzero(cooling & (dT < x))[0]] for x in (80.0, 40.0)]

    (c80, c40), (n80, n40) = rates("constant"), rates(law)
    assert (n80 / n40) / (c80 / c40) == pytest.approx(2 ** ind.CONVECTION_LAWS[law], rel=0.02)
    assert n40 < c40 < c80 < n80  # h as drawn at 50 K: less below, more above


def test_natural_convection_is_drawn_into_the_truth_and_bad_laws_are_named(tmp_path):
    _, truth = _small(tmp_path, "nat", convection="natural", n_recordings=2)
    assert truth["convection"] == "natural" and truth["baseline"]["h_exponent"] == 0.25
    _, same = _small(tmp_path, "const", n_recordings=2)
    assert same["convection"] == "constant" and same["baseline"]["h_exponent"] == 0.0
    assert same["baseline"]["h_W_m2K"] == truth["baseline"]["h_W_m2K"]  # the same rig otherwise
    with pytest.raises(ValueError, match="unknown convection 'forced'"):
        _small(tmp_path, "bad", convection="forced")


def test_fatigue_lowers_the_bend_and_leaves_the_rest_state():
    _, cmd = _pulse_cmd(8.0)
    fat = {"sma_fatigue": {"rate": 0.05, "max_loss": 0.4}}
    state = np.zeros(6)
    fresh = ind.simulate_recording(ind.CALIBRATED, cmd, effects=fat, fatigue_state=state)
    assert state[:2].min() > 0.5 and state[2:].max() < 0.05  # only the powered muscle wears
    worn = ind.simulate_recording(ind.CALIBRATED, cmd, effects=fat,
                                  fatigue_state=np.full(6, 10.0))
    assert worn["theta_deg"].max() < 0.9 * fresh["theta_deg"].max()
    assert worn["theta_deg"][:90].max() < 1e-6  # still upright before the pulse


def test_payload_and_friction_act_on_the_head():
    _, cmd = _pulse_cmd(6.0, dur=20.0)
    base = ind.simulate_recording(ind.CALIBRATED, cmd)
    heavy = ind.simulate_recording(ind.CALIBRATED, cmd, effects={
        "head_payload": {"mass_kg": 0.4, "com_height_m": 0.08}})
    assert heavy["theta_deg"].max() > base["theta_deg"].max() + 1.0
    stuck = ind.simulate_recording(ind.CALIBRATED, cmd, effects={
        "backbone_friction": {"friction_Nm": 0.05}})
    assert stuck["theta_deg"][:150].max() == 0.0  # no motion until the pull beats friction
    assert stuck["theta_deg"].max() < base["theta_deg"].max()


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match="unknown effect"):
        ind.generate(tmp_path / "x", ["no_such_effect"])
    with pytest.raises(ValueError, match="baseline"):
        ind.generate(tmp_path / "x", None, baseline="narrow")
    with pytest.raises(ValueError, match="unknown parameter"):
        ind.generate(tmp_path / "x", {"actuation_delay": {"delay": 0.3}})
    assert ind.main([str(tmp_path / "y"), "--effects", "bogus"]) == 2


def test_cooled_starts_carry_the_state_through_the_wait_for_rest(tmp_path):
    """``starts="cooled"``: the state carries over through the rig protocol's wait (relays off
    until the springs are within 3 K of ambient, then 20 s), so this rig's own stiction holds
    the neck off upright at the next start: less than the own model's (cold pennate springs
    pull it back; 0.46-0.53 deg at 0.05 N m on seed 3's rig), but clearly more than the same
    rig without friction (under 0.06 deg: the cold springs' hysteresis). ``upright`` resets
    every start, as before."""
    fr = {"backbone_friction": {"friction_Nm": 0.05}}
    _, held = _small(tmp_path, "held", fr, seed=3, starts="cooled", temperatures=True)
    _, free = _small(tmp_path, "free", None, seed=3, starts="cooled", temperatures=True)
    _, reset = _small(tmp_path, "reset", fr, seed=3, temperatures=True)
    off = lambda truth: [float(np.hypot(*r["start_true_tilt_deg"])) for r in truth["recordings"]]
    assert off(held)[0] == 0.0 and off(reset) == [0.0] * 6
    assert min(off(held)[1:]) > 0.3, off(held)
    assert max(off(free)) < 0.1, off(free)
    # the wait itself: at least the 20 s hold, longer after a pulse (the springs cool first)
    waits = [r["waited_s"] for r in held["recordings"][1:]]
    assert min(waits) >= 20.0 and max(waits) > 25.0, waits
    # its end is where the next recording starts: simulating the wait again lands there
    p = ind.CALIBRATED
    state, fat = ind.rest_state(p), np.zeros(6)
    _, cmd = _pulse_cmd(7.0)
    ind.simulate_recording(p, cmd, effects=fr, fatigue_state=fat, state=state)
    assert state[:6].max() > p.ambient_C + 20  # hot at the end of the recording
    ind.wait_for_rest(p, state, fat, fr)
    assert state[:6].max() - p.ambient_C <= 3.0 and np.hypot(*state[24:26]) > 0.0
    with pytest.raises(ValueError, match="unknown starts 'warm'"):
        ind.generate(tmp_path / "x", None, starts="warm")
    with pytest.raises(ValueError, match="state must be"):
        ind.simulate_recording(p, cmd, state=np.zeros(3))
