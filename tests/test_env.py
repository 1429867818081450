"""NeckTrack-v0: conformance, batching, budget, bad input, rendering, seeding."""

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import neck_env  # noqa: F401
from neck_env.envs import NeckTrackVectorEnv


@pytest.mark.parametrize("mode", ["current", "relay"])
def test_gymnasium_and_sb3_checkers_pass(mode):
    env = gym.make("NeckTrack-v0", action_mode=mode, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the [0, 8] A Box is deliberate (physical units)
        check_env(env.unwrapped)
        sb3_check_env(env.unwrapped)
    assert env.unwrapped.dt == pytest.approx(0.05)


def test_make_vec_is_native_batched():
    env = gym.make_vec("NeckTrack-v0", num_envs=5, vectorization_mode="vector_entry_point")
    assert isinstance(env.unwrapped, NeckTrackVectorEnv)
    obs, info = env.reset(seed=0)
    assert obs.shape == (5, 8)
    assert info["temperatures_C"].shape == (5, 3)
    assert env.unwrapped.dt == pytest.approx(0.05)


@pytest.mark.parametrize("mode", ["current", "relay"])
def test_vector_rollouts_equal_single_rollouts(mode):
    n, seed = 3, 11
    kw = dict(action_mode=mode, episode_s=5.0, randomize=True,
              effects=["imu_misalignment", "actuation_delay"])
    venv = gym.make_vec("NeckTrack-v0", num_envs=n, vectorization_mode="vector_entry_point", **kw)
    singles = [gym.make("NeckTrack-v0", **kw) for _ in range(n)]
    obs_v, _ = venv.reset(seed=seed)
    obs_s = [s.reset(seed=seed + i)[0] for i, s in enumerate(singles)]
    np.testing.assert_allclose(obs_v, np.array(obs_s), atol=1e-9)
    rng = np.random.default_rng(0)
    steps = singles[0].unwrapped.task.episode_steps
    for t in range(2 * steps + 5):
        if mode == "relay":
            a = rng.integers(0, 2, (n, 3))
        else:
            a = rng.uniform(0, 8, (n, 3)).astype(np.float32)
        obs_v, r_v, term_v, trunc_v, info_v = venv.step(a)
        for i, s in enumerate(singles):
            if t in (steps, 2 * steps + 1):  # vector autoreset step (NEXT_STEP mode)
                o, info = s.reset()
                assert r_v[i] == 0.0 and not trunc_v[i]
            else:
                o, r, term, trunc, info = s.step(a[i])
                assert r_v[i] == pytest.approx(r, abs=1e-9)
                assert trunc_v[i] == trunc and term_v[i] == term
                assert info_v["theta_deg"][i] == pytest.approx(info["theta_deg"], abs=1e-9)
                assert info_v["energy_J"][i] == pytest.approx(info["energy_J"], abs=1e-9)
            np.testing.assert_allclose(obs_v[i], o, atol=1e-9)


def test_budget_is_never_exceeded_and_cuts_actuation():
    budget = 60.0
    env = gym.make("NeckTrack-v0", energy_budget_J=budget)
    obs, _ = env.reset(seed=0)
    assert obs[7] == 1.0
    exhausted_at = None
    for t in range(400):
        obs, _, _, _, info = env.step(np.full(3, 8.0, dtype=np.float32))
        assert info["energy_J"] <= budget + 1e-9
        assert info["energy_J"] + info["energy_left_J"] == pytest.approx(budget, abs=1e-9)
        if info["budget_exhausted"] and exhausted_at is None:
            exhausted_at = t
        if exhausted_at is not None and t > exhausted_at:
            np.testing.assert_array_equal(info["currents_A"], 0.0)
            assert obs[7] == 0.0
    assert exhausted_at is not None and exhausted_at < 100
    assert info["energy_J"] == pytest.approx(budget, rel=1e-12)


def test_vector_budget_never_exceeded():
    env = gym.make_vec("NeckTrack-v0", num_envs=64, vectorization_mode="vector_entry_point",
                       energy_budget_J=30.0)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    for _ in range(200):
        _, _, _, _, info = env.step(rng.uniform(0, 8, (64, 3)).astype(np.float32))
        assert np.all(info["energy_J"] <= 30.0 + 1e-9)


@pytest.mark.parametrize("mode, bad, match", [
    ("current", [np.nan, 0, 0], "finite"),
    ("current", [np.inf, 0, 0], "finite"),
    ("current", [1.0, 2.0], "shape"),
    ("current", [[1.0, 2.0, 3.0]], "shape"),
    ("relay", [1, 0, 2], "0 or 1"),
    ("relay", [0.5, 0, 0], "0 or 1"),
    ("current", ["a", "b", "c"], "numeric"),
])
def test_invalid_actions_raise(mode, bad, match):
    env = gym.make("NeckTrack-v0", action_mode=mode)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.unwrapped.step(np.array(bad))


def test_vector_invalid_action_raises():
    env = gym.make_vec("NeckTrack-v0", num_envs=2, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([[0, 0, 0], [0, np.nan, 0]]))


@pytest.mark.parametrize("kwargs, match", [
    (dict(action_mode="pwm"), "action_mode"),
    (dict(energy_budget_J=-1.0), "energy_budget_J"),
    (dict(supply_current_A=12.0), "supply_current_A"),
    (dict(dt=0.0), "dt"),
    (dict(effects={"imu_misalignment": {"yaw_deg": 90.0}}), "yaw_deg"),
    (dict(effects=["draft"]), "unknown effect"),
])
def test_invalid_configuration_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("NeckTrack-v0", **kwargs)


def test_render_shape_and_content():
    env = gym.make("NeckTrack-v0", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.shape == (320, 640, 3) and first.dtype == np.uint8
    for _ in range(100):
        env.step(np.array([7.0, 0.0, 0.0], dtype=np.float32))
    bent = env.render()
    assert bent.shape == (320, 640, 3)
    # The drawing changed where the neck is (left panel) -- it bent and a muscle heated.
    assert np.abs(bent[:, :320].astype(int) - first[:, :320].astype(int)).sum() > 10000


def test_same_seed_same_trajectory_different_seed_different():
    def run(seed):
        env = gym.make("NeckTrack-v0", randomize=True)
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for t in range(300):
            out.append(env.step(np.array([6.0 * (t < 100), 0, 3.0], dtype=np.float32))[0])
        return np.array(out)

    a, b, c = run(5), run(5), run(6)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1


def test_heating_muscle_1_bends_toward_180_and_imu_follows():
    env = gym.make("NeckTrack-v0")
    env.reset(seed=2)
    for _ in range(120):
        obs, _, _, _, info = env.step(np.array([7.0, 0.0, 0.0], dtype=np.float32))
    assert info["theta_deg"] > 10.0
    assert abs(info["phi_deg"] - 180.0) < 1e-6
    true_tilt = info["theta_deg"] * np.array([math.cos(math.radians(info["phi_deg"])),
                                               math.sin(math.radians(info["phi_deg"]))])
    assert np.abs(obs[:2] - true_tilt).max() < 2.0  # IMU bias + noise + filter lag
    assert obs[2] > 60.0 and abs(obs[3] - 25.0) < 3.0


def test_imu_misalignment_yaw_shifts_measured_phi():
    env = gym.make("NeckTrack-v0", effects={"imu_misalignment": {"yaw_deg": 15.0, "tilt_deg": 0.0}},
                   sensors=neck_env.sensors.SensorParams(accel_noise_g=0, gyro_noise_dps=0,
                                                         accel_bias_g=0, gyro_bias_dps=0))
    env.reset(seed=0)
    for _ in range(200):
        obs, _, _, _, info = env.step(np.array([7.0, 0.0, 0.0], dtype=np.float32))
    measured_phi = math.degrees(math.atan2(obs[1], obs[0])) % 360
    # IMU rotated +15 deg about the head axis: the same bend reads 15 deg lower in its frame.
    assert measured_phi == pytest.approx(180.0 - 15.0, abs=0.3)
    assert info["phi_deg"] == pytest.approx(180.0, abs=1e-6)


def test_truncation_after_episode_s():
    env = gym.make("NeckTrack-v0", episode_s=1.0)
    env.reset(seed=0)
    for t in range(20):
        _, _, term, trunc, _ = env.step(np.zeros(3, dtype=np.float32))
        assert not term
        assert trunc == (t == 19)


def test_over_temperature_cut_holds_springs_near_cutoff():
    env = gym.make("NeckTrack-v0", energy_budget_J=float("inf"), cutoff_C=120.0)
    env.reset(seed=0)
    cut_seen = False
    for _ in range(600):
        _, _, _, _, info = env.step(np.array([8.0, 0.0, 0.0], dtype=np.float32))
        # One 50 ms step at 8 A heats a spring by < 2.5 K, so it never passes the cut by more.
        assert info["temperatures_C"][0] < 120.0 + 2.5
        if info["currents_A"][0] == 0.0:
            cut_seen = True
            assert info["temperatures_C"][0] >= 120.0 - 2.5
    assert cut_seen


def test_targets_stay_inside_the_reachable_workspace():
    from neck_env.targets import TargetSpec, sample_targets

    spec = TargetSpec()
    rng = np.random.default_rng(0)
    for _ in range(200):
        _, _, way, n = sample_targets(spec, 60.0, rng, spec.max_segments(60.0))
        theta = np.hypot(way[:n, 0], way[:n, 1])
        phi = np.arctan2(way[:n, 1], way[:n, 0])
        bound = np.array([spec.theta_max_at(p) for p in phi])
        assert np.all(theta <= bound + 1e-9)
    assert spec.theta_max_at(math.pi) == pytest.approx(25.0)  # toward muscle 1
    assert spec.theta_max_at(0.0) == pytest.approx(18.0)  # between muscles 2 and 3
