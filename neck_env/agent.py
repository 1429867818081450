"""What drives a NeckTrack env from outside the library, and how the library finds it.

``neck_env`` never imports its consumers: the controllers and the trained policies live in the
``agents`` package (or in yours). Commands of the library that run an agent -- ``python -m
neck_env.rig run --controller NAME | --policy PATH`` -- find them through the entry-point group
``neck_env.agents``. Each entry point names an object (a module is fine) with::

    controller_names() -> Sequence[str]
    make_controller(name: str, env_kwargs: dict) -> Agent      # ValueError for an unknown name
    load_policy(path: str) -> Agent                            # the policy's own env_kwargs

This project's ``pyproject.toml`` registers ``agents.provider``; a package of your own registers
itself the same way (``[project.entry-points."neck_env.agents"]``) and its controllers appear in
the rig CLI. ``register`` adds a provider in-process (scripts, tests).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, Protocol, Sequence

import numpy as np

ENTRY_POINT_GROUP = "neck_env.agents"


@dataclass(frozen=True)
class Agent:
    """One observation in, one action out, for one env; ``reset`` at each episode start."""

    label: str
    reset: Callable[[], None]
    act: Callable[[np.ndarray], np.ndarray]
    # The task keyword arguments it was built or trained for (a policy's action_mode,
    # supply_current_A, dt, ...); the env must offer this interface.
    env_kwargs: dict[str, Any] = field(default_factory=dict)


class AgentProvider(Protocol):
    def controller_names(self) -> Sequence[str]: ...

    def make_controller(self, name: str, env_kwargs: dict[str, Any]) -> Agent: ...

    def load_policy(self, path: str) -> Agent: ...


_registered: list[AgentProvider] = []


def register(provider: AgentProvider) -> None:
    """Make ``provider``'s controllers and policies available in this process."""
    if provider not in _registered:
        _registered.append(provider)


def providers() -> list[AgentProvider]:
    """Registered in-process first, then every installed ``neck_env.agents`` entry point."""
    found = list(_registered)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        p = ep.load()
        if p not in found:
            found.append(p)
    return found


def _need_providers() -> list[AgentProvider]:
    found = providers()
    if not found:
        raise ValueError(f"no controllers or policies are installed (entry-point group "
                         f"{ENTRY_POINT_GROUP!r} is empty): install this project with "
                         f"`pip install -e .` (or reinstall it after an update), which "
                         f"registers the agents package")
    return found


def controller_names() -> list[str]:
    return sorted({n for p in _need_providers() for n in p.controller_names()})


def make_controller(name: str, env_kwargs: dict[str, Any]) -> Agent:
    for p in _need_providers():
        if name in p.controller_names():
            return p.make_controller(name, dict(env_kwargs))
    raise ValueError(f"unknown controller {name!r}; known: {controller_names()}")


def load_policy(path: str) -> Agent:
    """The first provider's policy loader (policy files name their own algorithm)."""
    return _need_providers()[0].load_policy(str(path))
