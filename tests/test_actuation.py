"""The firmware actuation option (``neck_env.actuation``) against the firmware's source and logic,
and NeckTrack-v1 (registration, checkers, what it changes against v0)."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import neck_env
from neck_env.actuation import (FIRMWARE, FW_DUTY, FW_STATE_DIM, FirmwareLimits, firmware_step,
                                 max_equivalent_current_A)
from neck_env.envs import NeckTrackEnv
from neck_env.targets import TargetSpec

CONFIG_H = Path(__file__).resolve().parents[1] / "firmware" / "src" / "config.h"
IS = 7.0
LIM = FIRMWARE.as_array()


def _define(name: str) -> int:
    m = re.search(rf"#define\s+{name}\s+(\d+)", CONFIG_H.read_text())
    assert m, f"{name} not in {CONFIG_H}"
    return int(m.group(1))


def test_limits_are_the_firmware_sources():
    assert FIRMWARE == FirmwareLimits(
        duty_window_ms=_define("DUTY_WINDOW_MS"), duty_max_permille=_define("DUTY_MAX_PERMILLE"),
        ontime_cap_ms=_define("ONTIME_CAP_MS"), lockout_ms=_define("LOCKOUT_MS"),
        duty_bucket_cap_ms=_define("DUTY_BUCKET_CAP_MS"),
        duty_bucket_drain=_define("DUTY_BUCKET_DRAIN"))


def _run(commands_A, relay=False, phase_ms=0, step_ms=50):
    """Feed one command per step; per-step RMS currents (steps, 3) and refused masks."""
    state = np.zeros((3, FW_STATE_DIM))
    out, cur, refused = np.zeros(3), [], []
    for j, c in enumerate(commands_A):
        refused.append(firmware_step(state, float(phase_ms + j * step_ms),
                                     np.asarray(c, float), relay, IS, step_ms, LIM, out))
        cur.append(out.copy())
    return np.array(cur), refused


def test_duty_is_time_proportional_in_the_firmware_window():
    # duty 0.5 (I = I_s / sqrt 2) from window position 0: on for the window's first 500 ms
    cur, _ = _run([[IS / np.sqrt(2), 0.0, 0.0]] * 40)
    np.testing.assert_allclose(cur[:10, 0], IS)
    np.testing.assert_allclose(cur[10:20, 0], 0.0)
    np.testing.assert_allclose(cur[20:30, 0], IS)
    assert np.all(cur[:, 1:] == 0.0)
    # from window position 525 ms the same command is on only from the next window's start:
    # 25 ms of the first step are off-window ... until 1000
    cur, _ = _run([[IS / np.sqrt(2), 0, 0]] * 20, phase_ms=475)
    np.testing.assert_allclose(cur[0, 0], IS * np.sqrt(25 / 50))
    np.testing.assert_allclose(cur[1:10, 0], 0.0)
    np.testing.assert_allclose(cur[11:19, 0], IS)


@pytest.mark.parametrize("phase_ms", [0, 130, 999])
def test_duty_is_capped_at_80_percent(phase_ms):
    cur, _ = _run([[8.0, 6.0, 2.0]] * 40, phase_ms=phase_ms)
    mean_sq = np.mean(cur ** 2, axis=0)  # 40 steps = two whole windows
    np.testing.assert_allclose(mean_sq[0], 0.8 * IS ** 2)  # 8 A > I_s: capped
    np.testing.assert_allclose(mean_sq[1], 0.735 * IS ** 2)  # (6/7)^2 -> 735 permille, under
    np.testing.assert_allclose(mean_sq[2], round(1000 * (2 / IS) ** 2) / 1000 * IS ** 2)
    assert max_equivalent_current_A(IS) == pytest.approx(np.sqrt(0.8) * IS)


def test_duty_rounds_as_the_rig_env_sends_it():
    rng = np.random.default_rng(0)
    for c in rng.uniform(0, IS, (50, 3)):
        state = np.zeros((3, FW_STATE_DIM))
        firmware_step(state, 0.0, c, False, IS, 50, LIM, np.zeros(3))
        sent = [min(int(round(1000 * (x / IS) ** 2)), 800) for x in c]  # HardwareNeckEnv._step
        np.testing.assert_array_equal(state[:, FW_DUTY], sent)


def test_relay_on_time_cap_and_lockout():
    # held on: 10 s of continuous on-time, then off and locked out for 10 s (refused), then on
    cur, refused = _run([[1, 0, 0]] * 500, relay=True)
    on = cur[:, 0] > 0
    assert on[:200].all() and not on[200:400].any() and on[401:].all()
    assert all(r & 1 for r in refused[201:400]) and refused[0] == 0 and refused[401] == 0


def test_relay_sustained_duty_limiter_trips_and_drains():
    # 9.95 s on, 50 ms off: dodges the on-time cap but the long-run duty is 99.5 %
    pattern = ([[1, 0, 0]] * 199 + [[0, 0, 0]]) * 4
    cur, refused = _run(pattern, relay=True)
    on = cur[:, 0] > 0
    # bucket +9950 -200 per cycle: 19500 after two cycles, full 500 ms into the third
    first_off = 400 + np.argmin(on[400:599])
    assert first_off == 410
    # then refused until it has drained: 20000 / 4 = 5 s = 100 steps off
    assert not on[410:510].any() and all(refused[j] & 1 for j in range(411, 510))
    assert on[511:599].all()


def _hold(env, action, steps):
    cur = []
    for _ in range(steps):
        _, _, _, _, info = env.step(action)
        cur.append(info["currents_A"].copy())
    return np.array(cur)


def test_v1_is_registered_with_its_budget_and_firmware_actuation_and_v0_is_unchanged():
    v0, v1 = gym.make("NeckTrack-v0"), gym.make("NeckTrack-v1")
    assert v0.unwrapped.task.energy_budget_J == 1500.0 and v0.unwrapped.task.actuation == "ideal"
    t1 = v1.unwrapped.task
    assert t1.energy_budget_J == neck_env.V1_KWARGS["energy_budget_J"] == 900.0
    assert t1.actuation == "firmware"
    assert gym.make("NeckTrack-v1", energy_budget_J=500.0).unwrapped.task.energy_budget_J == 500.0
    vec = gym.make_vec("NeckTrack-v1", num_envs=2, vectorization_mode="vector_entry_point")
    assert vec.unwrapped.task == t1
    # v0 steady 8 A; v1 the firmware's duty windows at most sqrt(0.8) I_s
    v0.reset(seed=3), v1.reset(seed=3)
    c0 = _hold(v0, np.array([8.0, 0, 0], np.float32), 40)
    c1 = _hold(v1, np.array([8.0, 0, 0], np.float32), 40)
    np.testing.assert_allclose(c0[:, 0], 8.0)
    assert set(np.round(c1[:, 0] ** 2 / IS ** 2, 6)) <= {0.0, 1.0} | set(
        np.round(np.arange(51) / 50, 6))
    assert np.mean(c1[:, 0] ** 2) == pytest.approx(0.8 * IS ** 2)


def test_v1_relay_mode_meets_the_on_time_cap():
    env = NeckTrackEnv(action_mode="relay", actuation="firmware", energy_budget_J=float("inf"),
                       cutoff_C=1000.0, targets=TargetSpec(upright_probability=1.0))
    env.reset(seed=0)
    cur = _hold(env, np.array([1, 0, 0]), 260)
    assert np.all(cur[:200, 0] == IS) and np.all(cur[200:, 0] == 0.0)


def test_v1_vector_env_equals_single_envs():
    vec = gym.make_vec("NeckTrack-v1", num_envs=2, vectorization_mode="vector_entry_point")
    obs_v, _ = vec.reset(seed=7)
    singles = [gym.make("NeckTrack-v1") for _ in range(2)]
    obs_s = [e.reset(seed=7 + i)[0] for i, e in enumerate(singles)]
    rng = np.random.default_rng(1)
    for _ in range(60):
        a = rng.uniform(0, 8, (2, 3)).astype(np.float32)
        obs_v, r_v, *_ = vec.step(a)
        for i, e in enumerate(singles):
            o, r, *_ = e.step(a[i])
            np.testing.assert_array_equal(o, obs_v[i])
            assert r == r_v[i]


@pytest.mark.parametrize("mode", ["current", "relay"])
def test_v1_passes_the_gymnasium_and_sb3_checkers(mode):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("NeckTrack-v1", action_mode=mode)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    sb3_checker.check_env(NeckTrackEnv(**{**neck_env.V1_KWARGS, "action_mode": mode}), warn=True)


def test_firmware_actuation_changes_only_what_flows():
    """Same seed, same targets and sensor noise; the commanded 3 A flows as duty bursts."""
    a = NeckTrackEnv(actuation="ideal")
    b = NeckTrackEnv(actuation="firmware")
    oa, ia = a.reset(seed=5)
    ob, ib = b.reset(seed=5)
    np.testing.assert_array_equal(oa, ob)
    ca = _hold(a, np.array([3.0, 0, 0], np.float32), 20)
    cb = _hold(b, np.array([3.0, 0, 0], np.float32), 20)
    np.testing.assert_allclose(ca[:, 0], 3.0)
    assert np.mean(cb[:, 0] ** 2) == pytest.approx(round(1000 * (3 / IS) ** 2) / 1000 * IS ** 2)
    assert cb[:, 0].max() == pytest.approx(IS)
