"""The muscle-shared law (agents.muscle_policy) and its ARS training (agents.ars, policy: muscle):
w = 0 is a smoothed bang-bang, the safety layers hold whatever the weights, the batched rollouts
ARS scores are the episodes the deployed policy plays, and a tiny run ships a loadable policy."""

from __future__ import annotations

import json

import numpy as np
import pytest

import neck_env
from agents import benchmark
from agents.ars import ARSConfig, export_muscle, play, train, train_overrides
from agents.muscle_policy import FEATURES, N_FEATURES, SLOPE_PER_DEG, MusclePolicy, MuscleWeights
from agents.policy import DeployedPolicy
from neck_env.envs import NeckTrackEnv

KW = dict(neck_env.V1_KWARGS, episode_s=4.0, action_mode="current")


def _obs(target_deg=(10.0, 0.0), tilt_deg=(0.0, 0.0), temps_C=25.0, energy=1.0):
    return np.array([*tilt_deg, temps_C, temps_C, temps_C, *target_deg, energy], dtype=np.float32)


def _sigmoid(z):
    return 1.0 / (1.0 + np.exp(-z))


def test_zero_weights_are_a_smoothed_bang_bang_on_the_projected_error():
    pol = MusclePolicy(KW, 1, np.zeros(N_FEATURES))
    # target 10 deg toward muscle 1 (azimuth 180 deg): p = (10, -5, -5) deg on the three muscles
    cur = pol.act(_obs(target_deg=(-10.0, 0.0))[None])[0]
    p = np.array([10.0, -5.0, -5.0])
    # full on is the most the firmware's duty windows pass (0.89 I_s = 6.26 A at 7 A)
    assert pol.on_current_A == pytest.approx(7.0 * np.sqrt(0.8))
    np.testing.assert_allclose(cur, pol.on_current_A * _sigmoid(SLOPE_PER_DEG * (p - 1.0)), rtol=1e-5)
    assert cur[0] > 0.999 * pol.on_current_A and cur[1:].max() < 1e-6
    # at 1 deg of projected error the law is half on, at -0.5 deg nearly off
    pol.reset()
    cur = pol.act(_obs(target_deg=(-1.0, 0.0))[None])[0]
    assert cur[0] == pytest.approx(pol.on_current_A / 2, rel=1e-5)


def test_the_safety_layers_hold_whatever_the_weights():
    w = np.zeros(N_FEATURES)
    w[FEATURES.index("bias")] = 50.0  # a law that wants full current everywhere
    pol = MusclePolicy(KW, 1, w)
    assert pol.act(_obs()[None])[0].min() == pytest.approx(pol.on_current_A)
    hot = _obs(temps_C=151.0)
    assert pol.act(hot[None])[0].max() == 0.0  # the 150 degC cap ...
    assert pol.act(_obs(temps_C=145.0)[None])[0].max() == 0.0  # ... until 10 degC cooler
    assert pol.act(_obs(temps_C=139.0)[None])[0].min() == pytest.approx(pol.on_current_A)
    assert pol.act(_obs(energy=0.0)[None])[0].max() == 0.0  # budget spent


def test_relay_mode_is_sigma_delta_on_the_square_of_the_current_law():
    kw = dict(KW, action_mode="relay")
    pol = MusclePolicy(kw, 1, np.zeros(N_FEATURES))
    obs = _obs(target_deg=(-1.0, 0.0))  # muscle 1 half on: duty 0.25
    on = np.array([pol.act(obs[None])[0] for _ in range(400)])
    assert on.dtype == np.int8 and on[:, 0].mean() == pytest.approx(0.25, abs=0.01)


@pytest.mark.parametrize("mode", ["current", "relay"])
def test_batched_rollouts_are_the_episodes_the_deployed_policy_plays(tmp_path, mode):
    kw = dict(KW, action_mode=mode)
    rng = np.random.default_rng(0)
    W = np.stack([np.zeros(N_FEATURES), 0.5 * rng.standard_normal(N_FEATURES)])
    mse, outside = play(kw, 2, [11, 12], lambda n, cand: MusclePolicy(kw, n, W[cand]))
    assert mse.shape == outside.shape == (2, 2)
    assert mse[1].mean() != pytest.approx(mse[0].mean())
    cfg = ARSConfig(env_kwargs={"action_mode": mode}, episode_s=4.0, policy="muscle")
    export_muscle(tmp_path / "p", W[1], cfg, cfg.task_kwargs(), {})
    pol = DeployedPolicy.load(tmp_path / "p.zip", env_kwargs=kw)
    assert pol.meta["muscle"]["features"] == list(FEATURES)
    for j, seed in enumerate((11, 12)):
        env = NeckTrackEnv(**kw)
        obs, _ = env.reset(seed=seed)
        pol.reset()
        err = []
        for _ in range(env.task.episode_steps):
            obs, _, _, _, info = env.step(pol.act(obs))
            err.append(info["tracking_error_deg"])
        err = np.array(err)
        assert np.mean(err ** 2) == pytest.approx(mse[1, j], rel=1e-9)
        assert np.mean(err > 2.0) == pytest.approx(outside[1, j])


def test_weights_of_the_wrong_shape_are_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="proj_error"):
        MuscleWeights(np.zeros(N_FEATURES + 1))
    w = np.zeros(N_FEATURES)
    w[FEATURES.index("temp_rate")] = np.nan
    with pytest.raises(ValueError, match="temp_rate"):
        MuscleWeights(w)
    np.savez(tmp_path / "x.npz", W=np.zeros(3))
    with pytest.raises(ValueError, match="not a muscle policy"):
        MuscleWeights.load(tmp_path / "x.npz")


def test_training_episodes_cycle_through_the_configured_suites():
    cfg = ARSConfig(policy="muscle", train_suites=("nominal", "randomized", "effects"))
    over = train_overrides(cfg, np.random.default_rng(0), 6)
    assert over[0] == {} and over[3] == {}
    assert over[1] == over[4] == {"randomize": True}
    names = [o["effects"][0] for o in (over[2], over[5])]
    assert names[0] != names[1] and set(names) <= set(benchmark.EFFECT_NAMES)


def test_a_tiny_muscle_run_writes_a_benchmarkable_policy(tmp_path):
    cfg = ARSConfig(env_kwargs={"action_mode": "current"}, policy="muscle", iterations=2,
                    directions=2, top_directions=1, episodes_per_candidate=3, episode_s=3.0,
                    train_suites=("nominal", "randomized", "effects"), noise_std=0.3,
                    step_size=0.3, outside_weight_deg2=60.0, validation_seeds=(5000, 5001),
                    validate_every=1)
    lines = []
    meta = train(cfg, tmp_path, log=lines.append)
    assert len(lines) == 4 and "smoothed bang-bang" in lines[0] and "within 2 deg" in lines[1]
    rows = (tmp_path / "curve.csv").read_text().splitlines()
    assert rows[0].split(",")[-1] == "validation_within_2deg" and len(rows) == 4
    saved = json.loads((tmp_path / "policy.json").read_text())
    assert saved["config"]["train_suites"] == ["nominal", "randomized", "effects"]
    assert meta["trained"]["chosen_iteration"] in (0, 1, 2) and saved["obs_norm"] is None
    (tmp_path / "policy.zip").rename(tmp_path / "tiny_muscle.zip")
    (tmp_path / "policy.json").rename(tmp_path / "tiny_muscle.json")
    agent = benchmark.policy_agent(tmp_path / "tiny_muscle.zip",
                                   benchmark.suite_env_kwargs(3.0, 900.0, "current", "firmware"))
    agent.reset(0)
    assert agent.act(_obs()).dtype == np.float32


def test_a_bad_config_is_refused_by_name(tmp_path):
    for text, what in (("policy: lstm\n", "policy"), ("train_suites: [nominal, windy]\n", "train_suites"),
                       ("outside_weight_deg2: -1\n", "outside_weight_deg2")):
        path = tmp_path / "c.yml"
        path.write_text(text)
        with pytest.raises(SystemExit, match=what):
            ARSConfig.load(path)
