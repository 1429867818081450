"""The task object (neck_env.task): one definition for the sim envs, the rig env, the SB3
adapter and the controllers; action clipping; kwargs round trip; render modes; layers."""

import ast
import json
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import neck_env  # noqa: F401
from neck_env.targets import TargetSpec
from neck_env.task import INFO_KEYS, MAX_CURRENT_A, Task


def test_out_of_range_currents_are_clipped_like_gymnasium_box_envs():
    runs = []
    for action in ([9.5, -0.5, 3.0], [8.0, 0.0, 3.0]):
        env = gym.make("NeckTrack-v0")
        env.reset(seed=3)
        for _ in range(30):
            obs, r, _, _, info = env.step(np.array(action))
        runs.append((obs, r, info))
    (o1, r1, i1), (o2, r2, i2) = runs
    np.testing.assert_array_equal(o1, o2)
    assert r1 == r2
    np.testing.assert_array_equal(i1["currents_A"], i2["currents_A"])
    assert i1["currents_A"][0] == pytest.approx(8.0) and i1["currents_A"][1] == 0.0


def test_currents_scale_relays_by_the_supply_and_reject_what_cannot_be_clipped():
    t = Task(action_mode="relay", supply_current_A=6.0)
    np.testing.assert_array_equal(t.currents_A([1, 0, 1]), [[6.0, 0.0, 6.0]])
    np.testing.assert_array_equal(t.currents_A(np.array([[0, 1, 0], [1, 1, 1]]), 2),
                                  [[0, 6, 0], [6, 6, 6]])
    for bad, match in (([1, 0, 2], "0 or 1"), ([np.nan, 0, 0], "finite"), ([0, 0], "shape")):
        with pytest.raises(ValueError, match=match):
            t.currents_A(np.array(bad))
    c = Task().currents_A(np.array([[9.0, -1.0, np.float32(7.5)]]), 1)
    np.testing.assert_array_equal(c, [[MAX_CURRENT_A, 0.0, 7.5]])
    with pytest.raises(ValueError, match="finite"):
        Task().currents_A([np.inf, 0, 0])


def test_kwargs_round_trip_through_json_and_unknown_keys_are_named():
    t = Task(action_mode="relay", dt=0.1, episode_s=30.0, energy_budget_J=float("inf"),
             supply_current_A=6.5, cutoff_C=150.0,
             targets=TargetSpec(theta_max_deg=20.0, hold_s=(9.0, 15.0)))
    stored = json.loads(json.dumps(t.to_kwargs()))  # what a policy file holds
    assert Task.from_kwargs(stored) == t
    task, rest = Task.split_kwargs({"action_mode": "relay", "randomize": True, "params": "p.json"})
    assert task.action_mode == "relay" and rest == {"randomize": True, "params": "p.json"}
    with pytest.raises(TypeError, match="action_mdoe"):
        Task.from_kwargs({"action_mdoe": "relay"})
    with pytest.raises(TypeError, match="action_mdoe"):
        gym.make("NeckTrack-v0", action_mdoe="relay")
    env = gym.make("NeckTrack-v0", task=t)
    assert env.unwrapped.task is t and env.unwrapped.action_space == t.action_space


@pytest.mark.parametrize("kwargs, match", [
    (dict(dt=True), "dt"), (dict(cutoff_C=20.0), "cutoff_C"), (dict(episode_s=0.01), "episode_s"),
    (dict(targets={"theta_max": 3}), "unknown field"), (dict(energy_budget_J=float("nan")), "energy"),
])
def test_invalid_task_raises_naming_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Task.from_kwargs(kwargs)


def test_every_env_reports_the_task_info_keys():
    env = gym.make("NeckTrack-v0")
    _, info = env.reset(seed=0)
    assert tuple(info) == INFO_KEYS
    _, _, _, _, info = env.step(np.zeros(3, np.float32))
    assert tuple(info) == INFO_KEYS
    venv = gym.make_vec("NeckTrack-v0", num_envs=2, vectorization_mode="vector_entry_point")
    _, info = venv.reset(seed=0)
    assert tuple(k for k in info if not k.startswith("_")) == INFO_KEYS
    # fresh arrays: keeping an info must not alias the env's buffers
    keep = info["temperatures_C"].copy()
    venv.step(np.full((2, 3), 8.0, np.float32))
    np.testing.assert_array_equal(info["temperatures_C"], keep)


def test_controllers_take_the_same_task():
    from agents.controllers.base import ControlTask

    ct = ControlTask.from_env_kwargs({"action_mode": "relay", "supply_current_A": 6.0,
                                      "randomize": True})
    assert isinstance(ct, Task) and ct.max_current_A == 6.0
    with pytest.raises(ValueError, match="supply_current_A"):
        ControlTask.from_env_kwargs({"supply_current_A": 9.0})
    env = gym.make("NeckTrack-v0", action_mode="relay", episode_s=5.0)
    ct = ControlTask.from_env(env)
    assert Task.from_kwargs(ct.to_kwargs()) == env.unwrapped.task


@pytest.mark.parametrize("render_mode", [None, "rgb_array", "human"])
def test_gymnasium_checker_is_clean_in_every_render_mode(render_mode, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.setattr("matplotlib.pyplot.pause", lambda *_: None)
    env = gym.make("NeckTrack-v0", render_mode=render_mode).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
        sb3_check_env(env, skip_render_check=False)
    # the [0, 8] A Box in physical units is deliberate (SB3 training normalizes it itself)
    deliberate = ("symmetric and normalized", "precision")
    msgs = [str(w.message) for w in caught if not any(d in str(w.message) for d in deliberate)]
    assert msgs == [], msgs
    env.reset(seed=0)
    frame = env.render() if render_mode else None
    if render_mode == "human":
        assert frame is None
    elif render_mode == "rgb_array":
        assert frame.shape == (320, 640, 3)
    env.close()



# -- layers ----------------------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]


def test_the_library_never_imports_agents():
    offenders = []
    for path in (ROOT / "neck_env").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0
                     else [])
            offenders += [f"{path.relative_to(ROOT)}: {n}" for n in names
                          if n == "agents" or n.startswith("agents.")]
    assert offenders == []


def test_rig_commands_find_controllers_through_the_entry_point(monkeypatch):
    from neck_env import agent

    assert {"pid", "mpc", "zero"} <= set(agent.controller_names())
    a = agent.make_controller("pid", {"action_mode": "relay"})
    assert a.label == "pid" and a.env_kwargs == {"action_mode": "relay"}
    a.reset()
    assert a.act(np.zeros(8, np.float32)).dtype == np.int8  # relay encoding
    with pytest.raises(ValueError, match="unknown controller 'nope'.*pid"):
        agent.make_controller("nope", {})
    pol = agent.load_policy(str(ROOT / "agents" / "policies" / "ppo_necktrack.zip"))
    assert pol.label == "ppo_necktrack" and pol.env_kwargs["action_mode"] == "current"
    # nothing installed: the error says how to install it
    monkeypatch.setattr(agent, "entry_points", lambda group: [])
    monkeypatch.setattr(agent, "_registered", [])
    with pytest.raises(ValueError, match="pip install -e"):
        agent.make_controller("pid", {})
