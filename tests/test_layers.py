"""The package's layers: ``neck_env`` needs neither the learning stack nor its consumers.

``pip install neck_env`` (no extras) must give the env, the plant, the rig and the diagnosis;
torch, Stable-Baselines3 and tensorboard come with ``[train]``, and ``agents`` sits on top of
``neck_env``, never under it. The check runs in a fresh interpreter in which importing any of
them fails, as it would in a venv without them.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

BLOCKED = ("torch", "stable_baselines3", "sb3_contrib", "tensorboard", "agents", "ray")

SCRIPT = textwrap.dedent("""
    import importlib.abc, sys
    BLOCKED = set({blocked!r})

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"blocked in this test: {{name}}")
            return None

    sys.meta_path.insert(0, Block())
    import gymnasium
    import neck_env
    import neck_env.gap.diagnose, neck_env.gap.cli, neck_env.rig.cli, neck_env.rig.hardware_env
    for env_id in ("NeckTrack-v0", "NeckTrack-v1"):
        env = gymnasium.make(env_id)
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs), env_id
        env.close()
    loaded = sorted({{m.split(".")[0] for m in sys.modules}} & BLOCKED)
    assert not loaded, loaded
    print("ok")
""")


def test_neck_env_imports_and_runs_without_the_learning_stack_or_agents():
    out = subprocess.run([sys.executable, "-c", SCRIPT.format(blocked=BLOCKED)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-3000:]


def test_the_blocker_is_real():
    """The check above can fail: importing a blocked module in the same harness raises."""
    script = SCRIPT.format(blocked=BLOCKED).replace('print("ok")', "import agents")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode != 0 and "blocked in this test: agents" in out.stderr
