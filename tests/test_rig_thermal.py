"""The host's thermal estimate (no thermistors) is the simulator's own thermal model."""

from __future__ import annotations

import numpy as np
import pytest

from neck_env.params import default_params
from neck_env.physics import layout as L
from neck_env.physics.plant import constants_from_params, pulse_currents, simulate
from neck_env.rig.thermal_estimate import ThermalEstimate


def test_estimate_follows_the_plant_and_counts_its_joule_energy():
    est = ThermalEstimate()
    cur = pulse_currents([6.0], 1, 5.0, 15.0, 0.05)  # muscle 2, the paper's 5 s pulse
    traj, _ = simulate(constants_from_params(default_params()), cur, 0.05)
    energy = 0.0
    for k in range(cur.shape[0]):
        energy += est.advance(cur[k, 0], 0.05)
        np.testing.assert_allclose(est.temperatures_C, traj.T_C[k, 0], atol=1e-9)
    assert energy == pytest.approx(float((traj.power_W[:, 0].sum(axis=1) * 0.05).sum()), rel=1e-9)
    assert traj.T_C[:, 0, 1].max() > 70.0 and est.temperatures_C[0] == pytest.approx(25.0)
    # I^2 R with the phase-dependent resistance: between the martensite and austenite values
    c = constants_from_params(default_params())[0]
    lo, hi = sorted((c[L.R_M], c[L.R_A]))
    assert 2 * 36 * 5.0 * lo <= energy <= 2 * 36 * 5.0 * hi


def test_estimate_ambient_and_bad_input():
    est = ThermalEstimate(ambient_C=30.0)
    assert est.ambient_C == 30.0 and np.all(est.temperatures_C == 30.0)
    est.advance(np.zeros(3), 100.0)  # long idle in one call: sub-stepped, stays at ambient
    np.testing.assert_allclose(est.temperatures_C, 30.0, atol=1e-9)
    for bad in ([np.nan, 0, 0], [-1.0, 0, 0]):
        with pytest.raises(ValueError, match="finite and >= 0"):
            est.advance(np.array(bad), 0.05)
    with pytest.raises(ValueError, match="dt_s"):
        est.advance(np.zeros(3), -0.1)


def test_memory_carries_the_springs_between_processes_with_the_cooling(tmp_path):
    from neck_env.rig.memory import COLD_AFTER_S, RigMemory

    mem = RigMemory("/dev/ttyACM0", tmp_path)
    est = ThermalEstimate()
    assert "no earlier use" in mem.restore(est) and np.all(est.temperatures_C == 25.0)
    est.advance(np.array([7.0, 0.0, 0.0]), 5.0)
    mem.save(est, now_unix_s=1000.0)
    ref = ThermalEstimate()
    ref.load_state_vector(est.state_vector())
    ref.advance(np.zeros(3), 20.0)
    fresh = ThermalEstimate()
    note = RigMemory("/dev/ttyACM0", tmp_path).restore(fresh, now_unix_s=1020.0)
    assert "20 s ago" in note
    np.testing.assert_allclose(fresh.temperatures_C, ref.temperatures_C, atol=1e-9)
    assert fresh.temperatures_C[0] > 60.0
    # another port has its own history; a long idle is cold; a broken file is ignored
    other = ThermalEstimate()
    RigMemory("/dev/ttyACM1", tmp_path).restore(other, now_unix_s=1020.0)
    assert other.temperatures_C[0] == 25.0
    cold = ThermalEstimate()
    assert "idle" in mem.restore(cold, now_unix_s=1000.0 + COLD_AFTER_S + 1)
    assert cold.temperatures_C[0] == 25.0
    mem.path.write_text("{not json")
    broken = ThermalEstimate()
    assert "ignored unreadable" in mem.restore(broken, now_unix_s=1020.0)
    assert broken.temperatures_C[0] == 25.0
