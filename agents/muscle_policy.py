"""A muscle-shared policy: one small learned law, applied to each muscle in that muscle's frame.

Why this form: the three muscles are the same spring pair 120 deg apart, so what muscle k should
do depends only on the task *seen from muscle k* -- the tilt error projected on its direction,
its own temperature, how much budget and time are left. One law for all three has a third of the
parameters of three laws and is symmetric by construction. The law is logistic in the features::

    a_k = sigmoid(slope_per_deg * (p_k - on_deg) + w . phi_k)        in [0, 1]
    current mode: I_k = a_k * on_current_A;  relay mode: sigma-delta on a_k^2 (the same mean power)

With ``w = 0`` it is a smoothed bang-bang (slope 3/deg around 1 deg: full current from ~2.5 deg
of projected error, none below ~-0.5 deg). What the learned weights add is what bang-bang
lacks: switching off *before* the target while the spring is still contracting (its
temperature and heating rate, the tilt rate), spending the budget against the time left, and
an integral of the error for the steady state. The weights are found by ARS (``agents.ars``,
``policy: muscle``), which scores whole episodes, so a joule saved early is credited with what
it buys a minute later.

Features ``phi_k`` (``FEATURES``; every one on the rig too: the observation and the policy's
own memory)::

    | name             | value                                                  | scale   |
    |------------------|--------------------------------------------------------|---------|
    | proj_error       | p_k = (target - measured tilt) . u_k                   | 5 deg   |
    | target_proj      | target . u_k                                           | 10 deg  |
    | tilt_rate        | d/dt (measured tilt . u_k), smoothed (0.25 s)          | 5 deg/s |
    | temp_rise        | T_k - ambient (ambient: the first observation)         | 50 degC |
    | temp_rate        | dT_k/dt, smoothed (0.25 s)                             | 5 degC/s|
    | energy_left      | obs[7], the fraction of the budget left                | 1       |
    | time_left        | fraction of the episode left (the policy's step count) | 1       |
    | pace             | energy_left / time_left, clipped to [0, 3]             | 1       |
    | own_prev         | a_k at the previous step                               | 1       |
    | others_prev      | sum of the other two muscles' a at the previous step   | 1       |
    | error_x_energy   | clip(p_k, -3, 3) * energy_left                          | 3 deg   |
    | error_integral   | leaky (5 s) integral of clip(p_k, -5, 5)               | 10 deg s|
    | bias             | 1                                                      |         |

Safety, not learned: a muscle whose measured temperature reaches 150 degC gets no current until
it is 10 degC cooler (bang-bang's cap), and nothing flows once the budget is spent.

``MusclePolicy`` runs N envs at once (ARS's batched rollouts) or one (``DeployedPolicy``, the
benchmark, the rig): the same code path, so the deployed policy plays the episodes it was
scored on.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .controllers.allocation import muscle_unit_vectors
from .controllers.base import (DEFAULT_TEMP_CAP_C, OBS_ENERGY, OBS_TARGET, OBS_TEMPS, OBS_TILT,
                               ControlTask, SigmaDelta, ambient_from_start,
                               over_temperature)

FEATURES = ("proj_error", "target_proj", "tilt_rate", "temp_rise", "temp_rate", "energy_left",
            "time_left", "pace", "own_prev", "others_prev", "error_x_energy", "error_integral",
            "bias")
N_FEATURES = len(FEATURES)
SLOPE_PER_DEG = 3.0  # the fixed bang-bang part: logistic slope on the projected error ...
ON_DEG = 1.0  # ... centred here (bang-bang's default switch-on threshold)
RATE_SMOOTHING = 0.2  # exponential smoothing of the rates per 50 ms step (~0.25 s)
INTEGRAL_LEAK_S = 5.0
TEMP_BAND_C = 10.0
_SCALES = {"proj_error": 5.0, "target_proj": 10.0, "tilt_rate": 5.0, "temp_rise": 50.0,
           "temp_rate": 5.0, "error_integral": 10.0, "error_x_energy": 3.0}


class MuscleWeights:
    """The learned weights ``w`` (N_FEATURES,) that ``MusclePolicy`` applies, saved as an npz
    archive (no pickles)."""

    def __init__(self, w: np.ndarray):
        w = np.asarray(w, dtype=np.float64)
        if w.shape != (N_FEATURES,):
            raise ValueError(f"muscle policy weights must have shape ({N_FEATURES},) "
                             f"(features {FEATURES}), got {w.shape}")
        if not np.all(np.isfinite(w)):
            bad = [f for f, x in zip(FEATURES, w) if not np.isfinite(x)]
            raise ValueError(f"muscle policy weights must be finite; not finite: {bad}")
        self.w = w

    @classmethod
    def load(cls, path: str | Path) -> "MuscleWeights":
        with np.load(path) as d:
            if "w" not in d:
                raise ValueError(f"{path}: not a muscle policy (no array 'w'; has {sorted(d)})")
            return cls(d["w"])

    def save(self, path: str | Path) -> None:
        buf = io.BytesIO()
        np.savez(buf, w=self.w)
        Path(path).write_bytes(buf.getvalue())


class MusclePolicy:
    """N envs of the law in the module docstring. ``weights``: (N_FEATURES,) shared by every env,
    or (N, N_FEATURES), one row per env (ARS's candidates)."""

    def __init__(self, env_kwargs: Mapping[str, Any] | ControlTask | None, n: int,
                 weights: np.ndarray, on_current_A: float | None = None,
                 temp_cap_C: float = DEFAULT_TEMP_CAP_C):
        self.task = (env_kwargs if isinstance(env_kwargs, ControlTask)
                     else ControlTask.from_env_kwargs(env_kwargs))
        self.n = int(n)
        w = np.asarray(weights, dtype=np.float64)
        self.w = np.broadcast_to(w, (self.n, N_FEATURES)).copy()
        self.on_current_A = min(float(on_current_A if on_current_A is not None
                                      else self.task.supply_current_A), self.task.max_current_A)
        self.temp_cap_C = float(temp_cap_C)
        self.relay = self.task.action_mode == "relay"
        self.dt = self.task.dt
        self.u = muscle_unit_vectors(self.task.nominal_params().muscles.azimuths_deg)  # (3, 2)
        self.scale = np.array([_SCALES.get(f, 1.0) for f in FEATURES])
        self.modulator = SigmaDelta((self.n, 3))
        z3 = np.zeros((self.n, 3))
        self.prev_proj, self.prev_T, self.tilt_rate, self.temp_rate = (z3.copy() for _ in range(4))
        self.integral, self.a = z3.copy(), z3.copy()
        self.hot = np.zeros((self.n, 3), dtype=bool)
        self.ambient = np.zeros((self.n, 1))
        self.nominal_ambient_C = self.task.nominal_params().thermal.ambient_C
        self.steps = np.zeros(self.n, dtype=np.int64)

    def reset(self, ids: Sequence[int] | None = None) -> None:
        """Start an episode in envs ``ids`` (default all): the next ``act`` takes their first
        observation as the reset one (rates zero, ambient measured from it)."""
        ids = np.arange(self.n) if ids is None else np.asarray(ids, dtype=np.int64)
        self.steps[ids] = 0
        for arr in (self.tilt_rate, self.temp_rate, self.integral, self.a, self.modulator.acc):
            arr[ids] = 0.0
        self.hot[ids] = False

    def features(self, obs: np.ndarray) -> np.ndarray:
        """Advance the policy's memory by one observation (N, 8) and return phi (N, 3, F),
        scaled."""
        return self._observe(np.asarray(obs, dtype=np.float64).reshape(self.n, -1))[0]

    def _observe(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``features`` and the projected errors p (N, 3), deg, of observations (N, 8)."""
        proj = obs[:, OBS_TILT] @ self.u.T
        tgt = obs[:, OBS_TARGET] @ self.u.T
        T = obs[:, OBS_TEMPS]
        first = self.steps == 0
        if first.any():
            self.ambient[first, 0] = ambient_from_start(T[first], self.nominal_ambient_C)
            self.prev_proj[first], self.prev_T[first] = proj[first], T[first]
        p = tgt - proj
        al = RATE_SMOOTHING
        self.tilt_rate += al * ((proj - self.prev_proj) / self.dt - self.tilt_rate)
        self.temp_rate += al * ((T - self.prev_T) / self.dt - self.temp_rate)
        self.prev_proj, self.prev_T = proj, T.copy()
        self.integral = self.integral * (1.0 - self.dt / INTEGRAL_LEAK_S) + np.clip(p, -5, 5) * self.dt
        frac = obs[:, OBS_ENERGY:OBS_ENERGY + 1] * np.ones((1, 3))
        t_left = np.maximum(1.0 - self.steps * self.dt / self.task.episode_s, 0.0)[:, None] * np.ones((1, 3))
        phi = np.stack([p, tgt, self.tilt_rate, T - self.ambient, self.temp_rate, frac, t_left,
                        np.clip(frac / np.maximum(t_left, 0.05), 0.0, 3.0), self.a,
                        self.a.sum(axis=1, keepdims=True) - self.a,
                        np.clip(p, -3, 3) * frac, self.integral, np.ones_like(p)], axis=-1)
        self.hot = over_temperature(T, self.hot, self.temp_cap_C, TEMP_BAND_C)
        return phi / self.scale, p

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Env actions (N, 3) for the latest observations (N, 8): currents (float32) or relay
        states (int8)."""
        obs = np.asarray(obs, dtype=np.float64).reshape(self.n, -1)
        phi, p = self._observe(obs)
        z = SLOPE_PER_DEG * (p - ON_DEG) + np.einsum("nkf,nf->nk", phi, self.w)
        a = 1.0 / (1.0 + np.exp(-np.clip(z, -30.0, 30.0)))
        a = np.where(self.hot | (obs[:, OBS_ENERGY:OBS_ENERGY + 1] <= 0.0), 0.0, a)
        self.a = a
        self.steps += 1
        if self.relay:
            return self.modulator(a ** 2)
        return (a * self.on_current_A).astype(np.float32)
