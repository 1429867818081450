"""train.py and the SB3 adapter: a short run starts, saves, reloads and predicts."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env
from stable_baselines3.common.vec_env import VecEnv

import neck_env  # noqa: F401
from agents.policy import DeployedPolicy
from agents.sb3_env import NeckTrackSB3VecEnv, unit_to_current

ROOT = Path(__file__).resolve().parents[1]


def test_sb3_vecenv_autoresets_with_terminal_observation():
    env = NeckTrackSB3VecEnv(3, seed=4, episode_s=0.5)
    assert isinstance(env, VecEnv)
    obs = env.reset()
    assert obs.shape == (3, 8)
    for t in range(10):
        obs, rew, done, infos = env.step(np.full((3, 3), 5.0, dtype=np.float32))
        assert done.all() == (t == 9)
    assert all(info["TimeLimit.truncated"] for info in infos)
    assert all(info["terminal_observation"].shape == (8,) for info in infos)
    assert obs[0, 7] == 1.0  # the returned observation is the reset one: full budget again
    assert infos[0]["terminal_observation"][7] < 1.0


def test_unit_actions_map_onto_the_current_range():
    np.testing.assert_allclose(unit_to_current(np.array([-1.0, 0.0, 1.0, 2.0])), [0.0, 4.0, 8.0, 8.0])
    env = NeckTrackSB3VecEnv(2, seed=0, unit_actions=True)
    assert env.action_space.low.min() == -1.0 and env.action_space.high.max() == 1.0
    env.reset()
    _, _, _, _ = env.step(np.ones((2, 3), dtype=np.float32))
    np.testing.assert_allclose(env.venv.core.out[:, 8:11], 8.0)  # O_CURRENT: 8 A flowed


def test_single_env_passes_sb3_checker_in_relay_mode():
    check_env(gym.make("NeckTrack-v0", action_mode="relay").unwrapped)


@pytest.mark.slow
def test_short_training_run_saves_and_reloads(tmp_path):
    out = tmp_path / "run"
    ship = tmp_path / "shipped" / "policy"
    cmd = [sys.executable, str(ROOT / "train.py"), "--algo", "ppo", "--n-timesteps", "4096",
           "--n-envs", "8", "--out", str(out), "--eval-freq", "2048", "--eval-episodes", "1",
           "--save-freq", "2048", "--no-progress-bar", "--no-tensorboard", "--ship", str(ship),
           "--hyperparams", "n_steps=256", "batch_size=512", "--env-kwargs", "episode_s=5.0"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    for name in ("model.zip", "best_model.zip", "vecnormalize.pkl", "config.yml", "policy.zip",
                 "policy.json", "evaluations.npz"):
        assert (out / name).exists(), name
    assert list((out / "checkpoints").glob("model_*_steps.zip"))
    meta = json.loads(ship.with_suffix(".json").read_text())
    assert meta["algo"] == "PPO" and meta["frame_stack"] == 2 and meta["unit_actions"] is True
    assert len(meta["obs_norm"]["mean"]) == 8
    policy = DeployedPolicy.load(ship.with_suffix(".zip"))
    env = gym.make("NeckTrack-v0", **policy.env_kwargs)
    obs, _ = env.reset(seed=0)
    policy.reset()
    for _ in range(20):
        action = policy.act(obs)
        assert env.action_space.contains(np.asarray(action, dtype=np.float32))
        obs, *_ = env.step(action)


def test_train_help_explains_every_flag():
    res = subprocess.run([sys.executable, str(ROOT / "train.py"), "--help"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    for flag in ("--algo", "--config", "--seed", "--n-timesteps", "--n-envs", "--env-kwargs",
                 "--hyperparams", "--out", "--eval-freq", "--save-freq", "--tensorboard",
                 "--progress-bar", "--ship"):
        assert flag in res.stdout


def test_deployed_policy_missing_json_is_a_clear_error(tmp_path):
    (tmp_path / "p.zip").write_bytes(b"")
    with pytest.raises(FileNotFoundError, match="p.json"):
        DeployedPolicy.load(tmp_path / "p.zip")


def test_a_rejected_argument_leaves_no_run_folder(tmp_path):
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, str(ROOT / "train.py"), "--out", str(out),
                          "--env-kwargs", "action_mode=bogus", "--no-progress-bar"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode != 0 and "action_mode" in res.stderr
    assert not out.exists()


def test_vecnormalize_discounts_like_the_agent_and_rollouts_round_up():
    from agents.training import build_model, resolve_config, rollout_steps, vecnormalize_of

    run = resolve_config({"n_envs": 2, "n_timesteps": 100, "normalize": True, "gamma": 0.9,
                          "n_steps": 64, "batch_size": 64, "env_kwargs": {"episode_s": 2.0}})
    model, env = build_model("ppo", run, 0, None)
    assert vecnormalize_of(env, run).gamma == pytest.approx(0.9) == model.gamma
    assert rollout_steps(model) == 128  # n_steps x n_envs: learn(100) takes 128 steps
    model.learn(100)
    assert model.num_timesteps == 128


def test_residual_policy_starts_as_the_pid_and_round_trips(tmp_path):
    """A residual-on-PID model (agents.residual) with its zeroed last layer acts exactly as the
    PID through DeployedPolicy (the deployed features and combination are the training env's);
    a few PPO updates move it; the export carries the residual."""
    import neck_env
    from agents.controllers import make_controller
    from agents.policy import DeployedPolicy, export
    from agents.training import build_model, resolve_config, vecnormalize_of
    from neck_env.envs import NeckTrackEnv

    kw = dict(neck_env.V1_KWARGS, episode_s=3.0)
    run = resolve_config({"n_envs": 2, "n_timesteps": 256, "normalize": True,
                          "residual": {"base": "pid", "scale_A": 3.0}, "env_kwargs": kw,
                          "n_steps": 64, "batch_size": 64, "n_epochs": 1, "use_sde": True,
                          "policy_kwargs": "dict(log_std_init=-2.0)"})
    model, env = build_model("ppo", run, 0, None)
    assert env.observation_space.shape == (14,)
    path = export(model, tmp_path / "res", "ppo", kw, 1, vecnormalize_of(env, run), None, False,
                  "NeckTrack-v1", run.residual)
    pol = DeployedPolicy.load(path)
    assert pol.meta["residual"] == {"base": "pid", "scale_A": 3.0, "squared_error": False}
    e1, e2, pid = NeckTrackEnv(**kw), NeckTrackEnv(**kw), make_controller("pid", kw)
    (o1, _), (o2, _) = e1.reset(seed=4), e2.reset(seed=4)
    pid.reset(), pol.reset()
    for _ in range(e1.task.episode_steps):
        a1, a2 = pid.act(o1), pol.act(o2)
        np.testing.assert_array_equal(a1, a2)
        o1, *_ = e1.step(a1)
        o2, *_ = e2.step(a2)
    assert float(model.policy.action_net.weight.abs().max()) == 0.0
    model.learn(256)
    assert float(model.policy.action_net.weight.abs().max()) > 0.0  # trained: no longer the PID


def test_residual_relay_policy_outputs_relay_states():
    from agents.residual import ControllerResidual

    base = ControllerResidual({"action_mode": "relay", "actuation": "firmware"}, 2, 3.0)
    obs = np.zeros((2, 8), np.float32)
    obs[:, 2:5] = 25.0
    obs[:, 5] = 15.0  # target 15 deg toward muscle 1's side
    obs[:, 7] = 1.0
    base.features(obs)
    acts = [base.actions(np.array([[1.0, -1, -1], [-1.0, -1, -1]])) for _ in range(10)]
    acts = np.array(acts)
    assert acts.dtype == np.int8 and set(np.unique(acts)) <= {0, 1}
    # +3 A on muscle 0 in env 0 vs -3 A in env 1: more on-steps
    assert acts[:, 0, 0].sum() > acts[:, 1, 0].sum()


def test_a_zero_residual_on_bang_bang_is_bang_bang():
    import gymnasium as gym

    from agents.controllers import BangBangController
    from agents.controllers.base import ControlTask
    from agents.residual import ControllerResidual

    kw = {"action_mode": "current"}
    res = ControllerResidual(kw, 1, 3.0, base="bang_bang")
    ref = BangBangController(ControlTask.from_env_kwargs(kw))
    env = gym.make("NeckTrack-v1", **kw)
    obs, _ = env.reset(seed=3)
    res.reset([0])
    ref.reset()
    on = 0
    for _ in range(300):
        f = res.features(obs[None])
        a = res.actions(np.zeros((1, 3)))[0]
        b = ref.act(obs)
        np.testing.assert_allclose(a, b, atol=1e-6)
        on += int((a > 0).any())
        obs, *_ = env.step(a)
    assert on > 0  # it did heat: the comparison covers switching, not only zeros
    assert np.abs(f[0, 11:13]).sum() > 0  # the error integral it adds for a base without one
    with pytest.raises(ValueError, match="residual base 'mpc'"):
        ControllerResidual(kw, 1, 3.0, base="mpc")
