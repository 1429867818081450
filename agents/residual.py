"""Residual RL on top of a controller (the PID, or bang-bang): the policy outputs a bounded
correction to the base controller's current.

Why: the tracking error is an integrator's job and the PID already does it well; what it does
not know is the rest of the task -- the energy budget that binds on ``NeckTrack-v1``, the
firmware's duty windows and 6.26 A ceiling, the springs' hysteresis. Starting from the PID (the
policy's last layer starts at zero, so the untrained policy *is* the PID) RL only has to learn
the correction, and the PID's integral keeps the steady error down where a plain MLP policy
held its targets within 2 deg only half as often as the PID.

Per env step::

    base = controller.act(obs)  (its currents after its thermal cap and pacing governor, A, (3,))
    features = [obs (8), base / i_max (3), integral of the tilt error (2, deg s), elapsed
                episode fraction]     (base "pid": the PID's own, clamped integral)
    r = policy(features) in [-1, 1]^3
    I = clip(base + scale_A * r, 0, i_max)  -> current mode: I;  relay mode: sigma-delta on
                                              (I / I_s)^2, as the heuristics encode

``ResidualVecEnv`` is the SB3 training env (on the natively batched core, like
``agents.sb3_env``); ``ControllerResidual`` is the same computation for N envs, used by the
training env and by ``agents.policy.DeployedPolicy`` (meta ``"residual": {"base": "pid" |
"bang_bang", "scale_A"}``; no "base": the PID) in the benchmark and on the rig.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from gymnasium import spaces

from .controllers.bang_bang import BangBangController
from .controllers.base import OBS_TARGET, OBS_TILT, ControlTask, SigmaDelta
from .controllers.pid import PIDController

N_FEATURES = 14
BASES = {"pid": PIDController, "bang_bang": BangBangController}


class ControllerResidual:
    """N base controllers and the residual combination (see the module docstring)."""

    def __init__(self, env_kwargs: Mapping[str, Any] | None, n: int, scale_A: float,
                 base: str = "pid"):
        if base not in BASES:
            raise ValueError(f"residual base {base!r}: one of {sorted(BASES)}")
        self.task = ControlTask.from_env_kwargs(env_kwargs)
        self.n = int(n)
        self.scale_A = float(scale_A)
        self.base = base
        self.ctrls = [BASES[base](self.task) for _ in range(self.n)]
        self.mods = [SigmaDelta() for _ in range(self.n)]
        self.relay = self.task.action_mode == "relay"
        self.i_max = self.task.max_current_A
        self.base_A = np.zeros((self.n, 3))
        # a base without an integral of its own (bang-bang): the tilt error integrated here
        self.err_int = np.zeros((self.n, 2))

    def reset(self, ids: Sequence[int]) -> None:
        for i in ids:
            self.ctrls[i].reset()
            self.mods[i].reset()
            self.err_int[i] = 0.0

    def features(self, obs: np.ndarray, ids: Sequence[int] | None = None) -> np.ndarray:
        """Run the base controllers of envs ``ids`` (default all) once on their observations
        (N, 8) -- a controller must see each observation once -- and return the policy's
        features (N, 14) (rows not in ``ids``: zeros)."""
        obs = np.asarray(obs, dtype=np.float64).reshape(self.n, -1)
        f = np.zeros((self.n, N_FEATURES), dtype=np.float32)
        for i in (range(self.n) if ids is None else ids):
            c = self.ctrls[i]
            c.act(obs[i])
            self.base_A[i] = c.last_currents
            f[i, :8] = obs[i]
            f[i, 8:11] = c.last_currents / self.i_max
            if self.base == "pid":
                f[i, 11:13] = c.integral
            else:
                self.err_int[i] += (obs[i][OBS_TARGET] - obs[i][OBS_TILT]) * c.dt
                f[i, 11:13] = self.err_int[i]
            f[i, 13] = min(c.time_s / self.task.episode_s, 1.0)
        return f

    def actions(self, residual: np.ndarray) -> np.ndarray:
        """Env actions from the last base currents and the policy's residual (N, 3) in [-1, 1]."""
        r = np.clip(np.asarray(residual, dtype=np.float64).reshape(self.n, 3), -1.0, 1.0)
        cur = np.clip(self.base_A + self.scale_A * r, 0.0, self.i_max)
        if not self.relay:
            return cur.astype(np.float32)
        Is = self.task.supply_current_A
        return np.stack([m((cur[i] / Is) ** 2) for i, m in enumerate(self.mods)])


def feature_space() -> spaces.Box:
    return spaces.Box(-np.inf, np.inf, (N_FEATURES,), dtype=np.float32)


def make_residual_vec_env(num_envs: int, seed: int | None, scale_A: float,
                          env_kwargs: Mapping[str, Any], reseed_every_reset: bool = False,
                          squared_error: bool = False):
    """The SB3 VecEnv (import of SB3 deferred: the module is also used without training).
    ``reseed_every_reset``: every ``reset()`` starts from ``seed`` again (an evaluation env:
    each evaluation then runs the same episodes, so the training curve compares like with like).
    ``squared_error``: reward -e^2 / 10 (e in deg) instead of the env's -e: the benchmark ranks
    by RMSE, whose square is the mean of e^2, so this reward is what it scores (the large errors
    after a target step weigh more than a steady 1 deg)."""
    from .sb3_env import NeckTrackSB3VecEnv

    class ResidualVecEnv(NeckTrackSB3VecEnv):
        """SB3 VecEnv: observations are the residual features, actions the residual in [-1, 1]."""

        def __init__(self) -> None:
            super().__init__(num_envs, seed=seed, **dict(env_kwargs))
            self.base = ControllerResidual(env_kwargs, num_envs, scale_A)
            self.observation_space = feature_space()
            self.action_space = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
            self.reseed_every_reset = reseed_every_reset

        def _env_actions(self, actions):
            return self.base.actions(actions)

        def _observe(self, obs, ids=None):
            return self.base.features(obs, ids)  # runs the base controllers: once per observation

        def _rewards(self, core):
            return (-core.err ** 2 / 10.0 if squared_error else core.reward).astype(np.float32)

        def _reset_envs(self, ids):
            self.base.reset(ids)

    return ResidualVecEnv()
