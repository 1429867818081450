"""The agents package as seen by the library: its controllers and policies for commands of
``neck_env`` that run an agent (``python -m neck_env.rig run``), registered in
``pyproject.toml`` under the entry-point group ``neck_env.agents`` (see ``neck_env.agent``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from neck_env.agent import Agent


def controller_names() -> Sequence[str]:
    from .controllers import CONTROLLERS

    return tuple(CONTROLLERS)


def make_controller(name: str, env_kwargs: dict[str, Any]) -> Agent:
    from .controllers import make_controller as make

    ctrl = make(name, env_kwargs)
    return Agent(name, ctrl.reset, ctrl.act, dict(env_kwargs))


def load_policy(path: str) -> Agent:
    """A deployable policy (NAME.zip + NAME.json); needs the [train] extra (SB3, torch)."""
    try:
        import stable_baselines3  # noqa: F401
    except ImportError as exc:
        raise ValueError(f"running a trained policy needs Stable-Baselines3 and torch: "
                         f"pip install 'neck_env[train]' ({exc})") from None
    from .policy import DeployedPolicy

    pol = DeployedPolicy.load(path)  # reads the zip and its JSON once
    return Agent(Path(path).stem, pol.reset, pol.act, pol.env_kwargs)
