"""What every controller shares: the task it controls, the act() pipeline, the safety layers.

A controller drives ONE ``NeckTrack-v0`` env (or the rig, which builds the same observation)::

    ctrl = PIDController(env_kwargs)      # or ControlTask / None for the env defaults
    obs, info = env.reset(seed=s)
    ctrl.reset()                          # every episode
    while ...:
        obs, r, term, trunc, info = env.step(ctrl.act(obs))

``act(obs) -> action`` takes the raw observation (8,) and returns an action of the env's
``action_mode``: float32 currents (3,) in ``"current"`` mode, int8 relay states (3,) in
``"relay"`` mode. Inside, every controller computes a *continuous current demand* per muscle
(``_demand``) and the base class then applies, in order:

1. the **thermal limit** (springs burn): the current is capped so that a simple lumped thermal
   model of the muscle (heat capacity C, convection hA, hot resistance R; all from the nominal
   parameters) would not drive the measured spring temperature past ``temp_cap_C``:
   ``P_max = hA (T_cap - T_amb) + (C / tau_lim) (T_cap - T_meas)``, ``I_max = sqrt(P_max / R)``.
   Far below the cap this allows the full current; at the cap only the holding power;
   above it none. (Bang-bang replaces this with its own on/off hysteresis.)
2. the **energy pacing** governor: total electrical power is capped at
   ``burst x (energy left) / (time left)``, i.e. a controller may spend ``burst`` times the
   even pace for a while, but can never spend the whole budget early and be left without
   actuation. ``energy left`` comes from obs[7] (fraction) x the task's budget; time from the
   controller's own step count since ``reset``. Off when the budget is infinite.
3. **encoding** for the action mode: in current mode the demand is clipped to [0, 8] A; in relay
   mode a per-muscle first-order sigma-delta modulator turns it into on/off with the same mean
   *power* (duty = (I / I_supply)^2: Joule heat goes with I^2, and the 20 Hz switching is far
   faster than the ~20 s thermal time constant, so the springs see the average).

``ControlTask`` is the env's task (``neck_env.task.Task``: action mode, dt, episode length,
budget, supply current, cut, targets -- validated there) plus the nominal plant parameters a
controller models; build it from the env kwargs a policy was trained with
(``ControlTask.from_env_kwargs``) or from a live env (``ControlTask.from_env``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from neck_env.observation import OBS_DIM
from neck_env.params import NeckParams, resolve_params
from neck_env.physics import layout as L
from neck_env.physics.plant import constants_from_params
from neck_env.task import MAX_CURRENT_A, Task

# Observation indices (neck_env.observation).
OBS_TILT = slice(0, 2)
OBS_TEMPS = slice(2, 5)
OBS_TARGET = slice(5, 7)
OBS_ENERGY = 7

DEFAULT_TEMP_CAP_C = 150.0


@dataclass(frozen=True)
class ControlTask(Task):
    """The task as a controller sees it: the env's ``Task`` and the nominal plant model."""

    params: NeckParams | None = None  # nominal plant model; None = calibrated defaults

    @classmethod
    def from_env_kwargs(cls, env_kwargs: Mapping[str, Any] | None = None) -> "ControlTask":
        """From ``NeckTrack-v0`` keyword arguments (the simulation's other keys, such as
        ``randomize`` or ``effects``, are ignored: the controller models the nominal plant)."""
        task, rest = Task.split_kwargs(env_kwargs)
        params = rest.get("params")
        return cls.of(task, None if params is None else resolve_params(params))

    @classmethod
    def from_env(cls, env) -> "ControlTask":
        """From a live ``NeckTrackEnv`` (wrapped or not): its task and nominal parameters."""
        core = env.unwrapped.core
        return cls.of(core.task, core.params)

    @classmethod
    def of(cls, task: Task, params: NeckParams | None = None) -> "ControlTask":
        return cls(**{f: getattr(task, f) for f in Task.field_names()}, params=params)

    def nominal_params(self) -> NeckParams:
        return resolve_params(self.params)


def as_task(task: ControlTask | Mapping[str, Any] | None) -> ControlTask:
    if isinstance(task, ControlTask):
        return task
    return ControlTask.from_env_kwargs(task)


@dataclass(frozen=True)
class MuscleThermal:
    """Lumped thermal model of one muscle (its two springs in series), nominal parameters."""

    heat_capacity_J_K: float  # both springs
    convection_W_K: float  # hA, both springs
    resistance_ohm: float  # both springs, hot (austenite: the larger, so currents err low)
    ambient_C: float

    @classmethod
    def from_params(cls, params: NeckParams) -> "MuscleThermal":
        c = constants_from_params(params)[0]
        return cls(2 * c[L.HEAT_CAP], 2 * c[L.HA], 2 * c[L.R_A], float(c[L.AMBIENT]))

    @property
    def time_constant_s(self) -> float:
        return self.heat_capacity_J_K / self.convection_W_K

    def power_to_reach(self, T_set, T_now, tau_s: float, ambient_C: float | None = None):
        """Electrical power (W, >= 0) that holds ``T_set`` and closes the gap from ``T_now``
        with time constant ``tau_s`` (first-order inverse of C dT/dt = P - hA (T - T_amb))."""
        amb = self.ambient_C if ambient_C is None else ambient_C
        p = (self.convection_W_K * (np.asarray(T_set) - amb)
             + self.heat_capacity_J_K / tau_s * (np.asarray(T_set) - np.asarray(T_now)))
        return np.maximum(p, 0.0)

    def current_for_power(self, power_W):
        return np.sqrt(np.maximum(power_W, 0.0) / self.resistance_ohm)

    def power_of_current(self, current_A):
        return self.resistance_ohm * np.asarray(current_A) ** 2


def ambient_from_start(temps_C: np.ndarray, nominal_C: float) -> np.ndarray:
    """Springs start an episode at ambient: the first observation's three temperatures
    (..., 3) measure it (their mean); readings that cannot be room temperature (outside 0-45
    degC: no or a broken thermistor) keep the nominal value."""
    t0 = np.mean(temps_C, axis=-1)
    return np.where((t0 >= 0.0) & (t0 <= 45.0), t0, nominal_C)


def over_temperature(temps_C: np.ndarray, was_hot: np.ndarray, cap_C: float,
                     band_C: float) -> np.ndarray:
    """The temperature cap's hysteresis (springs burn): a spring is too hot at or above
    ``cap_C`` and stays so until it is below ``cap_C - band_C`` (any array shape)."""
    return np.where(temps_C >= cap_C, True, np.where(temps_C < cap_C - band_C, False, was_hot))


class SigmaDelta:
    """Per-muscle first-order sigma-delta modulator: duty in [0, 1] -> 0/1 with that mean
    (``shape``: (3,) for one env, (N, 3) for N)."""

    def __init__(self, shape: tuple[int, ...] = (3,)) -> None:
        self.acc = np.zeros(shape)

    def reset(self) -> None:
        self.acc[:] = 0.0

    def __call__(self, duty: np.ndarray) -> np.ndarray:
        self.acc += np.clip(duty, 0.0, 1.0)
        on = self.acc >= 0.5
        self.acc[on] -= 1.0
        return on.astype(np.int8)


class Controller:
    """Base class: see the module docstring. Subclasses implement ``_demand(obs) -> currents``."""

    name = "controller"
    kind = "heuristic"  # "heuristic" | "model-based" | "learned"
    thermal_limit = True  # apply the smooth thermal limit (bang-bang has its own)

    def __init__(self, task: ControlTask | Mapping[str, Any] | None = None, *,
                 temp_cap_C: float = DEFAULT_TEMP_CAP_C, burst: float = 4.0,
                 limit_tau_s: float = 0.5):
        self.task = as_task(task)
        self.params = self.task.nominal_params()
        self.thermal = MuscleThermal.from_params(self.params)
        self.temp_cap_C = float(temp_cap_C)
        self.burst = float(burst)
        self.limit_tau_s = float(limit_tau_s)
        self.dt = self.task.dt
        self.i_max = self.task.max_current_A
        self._modulator = SigmaDelta()
        self.steps = 0
        self.ambient_C = self.thermal.ambient_C
        self.last_currents = np.zeros(3)  # what the last act() asked to flow (after limits)
        self.last_demand = np.zeros(3)  # before limits

    @classmethod
    def for_env(cls, env, **options: Any) -> "Controller":
        """A controller for a live ``NeckTrackEnv`` (its task and nominal parameters)."""
        return cls(ControlTask.from_env(env), **options)

    # -- episode ------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Start an episode (clears integrators, estimators, modulator, step count)."""
        self.steps = 0
        self._modulator.reset()
        self.last_currents = np.zeros(3)
        self.last_demand = np.zeros(3)
        self._reset(seed)

    def _reset(self, seed: int | None) -> None:  # subclass hook
        pass

    # -- acting -------------------------------------------------------------------------------
    def act(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float64)
        if obs.shape != (OBS_DIM,):
            raise ValueError(f"act() takes one observation of shape ({OBS_DIM},), got {obs.shape}")
        if self.steps == 0:
            self.ambient_C = float(ambient_from_start(obs[OBS_TEMPS], self.thermal.ambient_C))
        demand = np.clip(np.nan_to_num(np.asarray(self._demand(obs), dtype=float)), 0.0, self.i_max)
        cur = demand.copy()
        if self.thermal_limit:
            cur = np.minimum(cur, self.thermal_cap(obs[OBS_TEMPS]))
        cur = self.pace(cur, obs[OBS_ENERGY])
        if obs[OBS_ENERGY] <= 0.0:
            cur[:] = 0.0  # budget spent: the env cuts actuation anyway
        self.last_demand, self.last_currents = demand, cur
        self._applied(obs, cur)
        self.steps += 1
        return self.encode(cur)

    def _demand(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _applied(self, obs: np.ndarray, currents: np.ndarray) -> None:
        """Hook: the currents actually requested this step (after limits), e.g. anti-windup."""

    # -- safety layers ------------------------------------------------------------------------
    def thermal_cap(self, temps_C: np.ndarray) -> np.ndarray:
        p = self.thermal.power_to_reach(self.temp_cap_C, temps_C, self.limit_tau_s, self.ambient_C)
        return self.thermal.current_for_power(p)

    @property
    def time_s(self) -> float:
        return self.steps * self.dt

    def energy_left_J(self, frac: float) -> float:
        return float(frac) * self.task.energy_budget_J

    def power_allowance_W(self, frac: float) -> float:
        """Total power the pacing governor allows now (inf without a budget)."""
        if not math.isfinite(self.task.energy_budget_J):
            return math.inf
        t_left = max(self.task.episode_s - self.time_s, self.dt)
        return self.burst * self.energy_left_J(frac) / t_left

    def pace(self, currents: np.ndarray, frac: float) -> np.ndarray:
        allow = self.power_allowance_W(frac)
        power = float(self.thermal.power_of_current(currents).sum())
        if power > allow:
            currents = currents * math.sqrt(allow / power)
        return currents

    # -- encoding -----------------------------------------------------------------------------
    def encode(self, currents: np.ndarray) -> np.ndarray:
        if self.task.action_mode == "relay":
            return self._modulator((currents / self.task.supply_current_A) ** 2)
        return np.clip(currents, 0.0, MAX_CURRENT_A).astype(np.float32)

    def describe(self) -> str:
        return self.name


class ZeroController(Controller):
    """Reference: never heats (the head stays upright)."""

    name = "zero"

    def _demand(self, obs):
        return np.zeros(3)


class FullOnController(Controller):
    """Reference: every muscle on at the largest current (8 A, or the supply in relay mode),
    no thermal limit, no pacing: what constant full heating costs. Symmetric, so the head
    stays upright while the budget drains."""

    name = "full_on"
    thermal_limit = False

    def __init__(self, task=None, **kw):
        super().__init__(task, **kw)
        self.burst = math.inf

    def pace(self, currents, frac):
        return currents

    def _demand(self, obs):
        return np.full(3, self.i_max)
