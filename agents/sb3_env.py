"""Stable-Baselines3 view of the natively batched NeckTrack env.

SB3 trains on its own ``VecEnv`` API (same-step autoreset, terminal observation in ``info``).
``NeckTrackSB3VecEnv`` gives it that on top of ``NeckTrackVectorEnv``'s compiled core, so
training steps all rigs in one call instead of N Python envs.

| SB3 expects                         | here                                                    |
|-------------------------------------|---------------------------------------------------------|
| ``reset() -> obs (N, 8)``           | seeds sub-env i with ``seed + i`` (``seed()`` sets it) |
| ``step(actions) -> obs, rew, done, infos`` | ``done = truncated`` (60 s episodes; no terminal states) |
| same-step autoreset                 | a done env is reset at once; ``infos[i]["terminal_observation"]`` holds its last observation and ``"TimeLimit.truncated"`` is True, so value bootstrapping stays right |
| a normalized Box action space       | ``unit_actions=True`` (current mode): actions in [-1, 1] map linearly onto [0, 8] A, so an untrained Gaussian policy explores around 4 A instead of clipping half its samples to 0 A |
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from neck_env.envs import NeckTrackVectorEnv
from neck_env.task import MAX_CURRENT_A


class NeckTrackSB3VecEnv(VecEnv):
    def __init__(self, num_envs: int, seed: int | None = None, unit_actions: bool = False,
                 **env_kwargs: Any):
        self.venv = NeckTrackVectorEnv(num_envs=num_envs, **env_kwargs)
        self.task = self.venv.task
        self.unit_actions = bool(unit_actions) and self.task.action_mode == "current"
        action_space = (spaces.Box(-1.0, 1.0, (3,), dtype=np.float32) if self.unit_actions
                        else self.venv.single_action_space)
        super().__init__(num_envs, self.venv.single_observation_space, action_space)
        self._seed = seed
        self._actions: np.ndarray | None = None
        # an evaluation env starts every reset() from ``seed`` again (same episodes each time)
        self.reseed_every_reset = False

    def reset(self) -> np.ndarray:
        obs, _ = self.venv.reset(seed=self._seed)
        if not self.reseed_every_reset:
            self._seed = None  # later resets continue each sub-env's own stream
        self._reset_envs(range(self.num_envs))
        return self._observe(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        core = self.venv.core
        core.step(self.task.currents_A(self._env_actions(self._actions), self.num_envs))
        obs = self._observe(core.obs.copy())
        rewards = self._rewards(core)
        dones = core.truncated.copy()
        err = core.err
        infos: list[dict[str, Any]] = [{"tracking_error_deg": float(e)} for e in err]
        if dones.any():
            ids = np.nonzero(dones)[0]
            for i in ids:
                infos[i]["terminal_observation"] = obs[i].copy()
                infos[i]["TimeLimit.truncated"] = True
                infos[i]["energy_J"] = float(core.energy_used[i])
            core.reset(ids, None)
            self._reset_envs(ids)
            obs[ids] = self._observe(core.obs, ids)[ids]
        return obs, rewards, dones, infos

    # What a view on top of the env changes (agents.residual): actions, observations, reward.
    def _env_actions(self, actions: np.ndarray) -> np.ndarray:
        return unit_to_current(actions) if self.unit_actions else actions

    def _observe(self, obs: np.ndarray, ids: Sequence[int] | None = None) -> np.ndarray:
        """The agent's observations from the env's (N, 8); ``ids``: only those envs are new."""
        return obs

    def _rewards(self, core) -> np.ndarray:
        return core.reward.astype(np.float32)

    def _reset_envs(self, ids: Sequence[int]) -> None:
        """Envs ``ids`` start a new episode (before their first observation)."""

    def close(self) -> None:
        self.venv.close()

    # The rest of the VecEnv API: attributes live on the shared vector env.
    def _indices(self, indices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return indices

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        return [getattr(self.venv, method_name)(*args, **kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def seed(self, seed: int | None = None) -> Sequence[None]:
        self._seed = seed
        return [None] * self.num_envs

    def get_images(self) -> Sequence[np.ndarray]:
        return [self.venv.render()]


def unit_to_current(u: np.ndarray) -> np.ndarray:
    """Map actions in [-1, 1] (clipped) linearly onto [0, MAX_CURRENT_A] amperes."""
    return (np.clip(np.asarray(u, dtype=np.float64), -1.0, 1.0) + 1.0) * (0.5 * MAX_CURRENT_A)
