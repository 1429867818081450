"""ARS of a linear residual on the PID (agents.ars): the batched rollouts it scores are the
episodes the deployed policy plays, W = 0 is the PID, and a tiny run ships a loadable policy."""

from __future__ import annotations

import json

import numpy as np
import pytest

import neck_env
from agents import benchmark
from agents.ars import ARSConfig, RunningStats, export, rollout, train
from agents.policy import DeployedPolicy
from agents.residual import N_FEATURES
from neck_env.envs import NeckTrackEnv

KW = dict(neck_env.V1_KWARGS, episode_s=4.0, action_mode="current")


def _episode_mse(agent_act, reset, seed, kw=KW):
    env = NeckTrackEnv(**kw)
    obs, _ = env.reset(seed=seed)
    reset()
    sq = []
    for _ in range(env.task.episode_steps):
        obs, _, _, _, info = env.step(agent_act(obs))
        sq.append(info["tracking_error_deg"] ** 2)
    return float(np.mean(sq))


def test_zero_weights_are_the_pid_and_batched_rollouts_equal_single_episodes(tmp_path):
    rng = np.random.default_rng(0)
    W = np.stack([np.zeros((3, N_FEATURES)), 0.3 * rng.standard_normal((3, N_FEATURES))])
    b = np.array([[0.0, 0, 0], [0.2, -0.1, 0.3]])
    mean, std = rng.normal(0, 1, N_FEATURES), rng.uniform(0.5, 2, N_FEATURES)
    mse = rollout(KW, 3.0, W, b, [11, 12], mean, std)
    assert mse.shape == (2, 2)
    pid = benchmark.controller_agent("pid", KW)
    for j, seed in enumerate((11, 12)):
        assert mse[0, j] == pytest.approx(_episode_mse(pid.act, lambda: pid.reset(seed), seed),
                                          rel=1e-9)
    # the exported candidate 1, played by DeployedPolicy one env at a time, scores the same
    cfg = ARSConfig(env_kwargs={"action_mode": "current"}, episode_s=4.0)
    export(tmp_path / "p", W[1], b[1], mean, std, cfg, cfg.task_kwargs(), {})
    pol = DeployedPolicy.load(tmp_path / "p.zip", env_kwargs=KW)
    assert pol.meta["algo"] == "ARS" and pol.meta["residual"]["scale_A"] == 3.0
    for j, seed in enumerate((11, 12)):
        assert _episode_mse(pol.act, pol.reset, seed) == pytest.approx(mse[1, j], rel=1e-4)
    assert mse[1].mean() != pytest.approx(mse[0].mean())


def test_running_stats_are_the_pooled_mean_and_variance():
    rng = np.random.default_rng(1)
    chunks = [rng.normal(3, 2, (k, 4)) for k in (5, 17, 1, 40)]
    s = RunningStats(4)
    for c in chunks:
        s.update(c)
    allx = np.concatenate(chunks)
    np.testing.assert_allclose(s.mean, allx.mean(axis=0))
    np.testing.assert_allclose(s.var, allx.var(axis=0))


def test_a_tiny_run_writes_a_benchmarkable_policy_and_curve(tmp_path):
    cfg = ARSConfig(env_kwargs={"action_mode": "relay"}, iterations=2, directions=2,
                    top_directions=1, episodes_per_candidate=1, episode_s=3.0,
                    validation_seeds=(5000, 5001), validate_every=1)
    lines = []
    meta = train(cfg, tmp_path, log=lines.append)
    assert len(lines) == 4 and "validation RMSE" in lines[1]
    assert (tmp_path / "policy.zip").exists() and (tmp_path / "curve.png").stat().st_size > 1000
    rows = (tmp_path / "curve.csv").read_text().splitlines()
    assert rows[0].startswith("iteration,") and len(rows) == 4
    assert json.loads((tmp_path / "policy.json").read_text())["env_kwargs"]["action_mode"] == "relay"
    assert meta["trained"]["chosen_iteration"] in (0, 1, 2)
    (tmp_path / "policy.zip").rename(tmp_path / "tiny_ars.zip")
    (tmp_path / "policy.json").rename(tmp_path / "tiny_ars.json")
    agent = benchmark.policy_agent(tmp_path / "tiny_ars.zip",
                                   benchmark.suite_env_kwargs(3.0, 900.0, "current", "firmware"))
    assert agent.env_kwargs["action_mode"] == "relay"
    agent.reset(0)
    assert agent.act(np.zeros(8, np.float32)).dtype == np.int8
