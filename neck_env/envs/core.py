"""The batched core both NeckTrack environments run on (the single env is a core with N = 1).

It owns the arrays of N rigs (plant state, sensors, targets, budgets) and advances them with two
compiled calls per step: the plant (``physics.plant.step_inplace``) and ``_sense`` (IMU,
complementary filter, thermistors, target, reward, observation). Sharing one core is what makes
a vector env's rollouts equal N single envs' rollouts with the same seeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from numba import njit, prange

from .. import effects as fx
from ..observation import FILTER_TAU_S, OBS_DIM, fill_observation, fuse_tilt, tilt_from_accel
from ..params import NeckParams, default_params
from ..physics import layout as L
from ..physics.plant import PARALLEL_FROM, constants_from_params, initial_state, step_inplace
from ..sensors import SensorParams, imu_reading, next_normal
from ..targets import TargetSpec, sample_targets, target_at, tracking_error_deg

ACTION_MODES = ("current", "relay")
MAX_CURRENT_A = 8.0
DEFAULT_DT_S = 0.05
DEFAULT_EPISODE_S = 60.0
DEFAULT_SUPPLY_A = 7.0  # calibrated Table 1: a 5 s pulse at 7 A reaches ~24 deg (task range)
DEFAULT_BUDGET_J = 1500.0  # see README "Energy budget"


@dataclass(frozen=True)
class Randomization:
    """Per-episode domain randomization of the plant (multipliers and shifts of the defaults)."""

    convection_scale: tuple[float, float] = (0.75, 1.33)
    bending_stiffness_scale: tuple[float, float] = (0.8, 1.25)
    stress_coefficient_scale: tuple[float, float] = (0.8, 1.25)
    recoverable_strain_scale: tuple[float, float] = (0.85, 1.15)
    heat_capacity_scale: tuple[float, float] = (0.9, 1.1)
    resistance_scale: tuple[float, float] = (0.95, 1.05)
    transformation_shift_C: tuple[float, float] = (-4.0, 4.0)
    ambient_C: tuple[float, float] = (18.0, 32.0)

    def __post_init__(self) -> None:
        for name, (lo, hi) in self.__dict__.items():
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"randomization.{name} = {(lo, hi)}: need finite low <= high")

    def apply(self, row: np.ndarray, rng: np.random.Generator) -> None:
        """Perturb one constants row in place."""
        u = lambda r: rng.uniform(*r)
        s = u(self.convection_scale)
        row[L.HA] *= s
        row[L.K_BEND] *= u(self.bending_stiffness_scale)
        s = u(self.stress_coefficient_scale)
        row[L.C_A] *= s
        row[L.C_M] *= s
        row[L.GAMMA_L] *= u(self.recoverable_strain_scale)
        s = u(self.heat_capacity_scale)
        row[L.HEAT_CAP] *= s
        row[L.LATENT_J] *= s
        s = u(self.resistance_scale)
        row[L.R_M] *= s
        row[L.R_A] *= s
        shift = u(self.transformation_shift_C)
        for col in (L.AS, L.AF, L.MS, L.MF):
            row[col] += shift
        row[L.AMBIENT] = u(self.ambient_C)


@dataclass(frozen=True)
class TaskConfig:
    """Everything that defines a NeckTrack task instance (shared by the sim and rig envs)."""

    action_mode: str = "current"
    dt: float = DEFAULT_DT_S
    episode_s: float = DEFAULT_EPISODE_S
    energy_budget_J: float = DEFAULT_BUDGET_J
    supply_current_A: float = DEFAULT_SUPPLY_A
    targets: TargetSpec = field(default_factory=TargetSpec)

    def __post_init__(self) -> None:
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        if not (isinstance(self.dt, (int, float)) and 0.001 <= self.dt <= 1.0):
            raise ValueError(f"dt = {self.dt!r}: must be a number of seconds in [0.001, 1]")
        if not (isinstance(self.episode_s, (int, float)) and self.dt <= self.episode_s < 1e6):
            raise ValueError(f"episode_s = {self.episode_s!r}: must be >= dt and finite")
        b = self.energy_budget_J
        if not (isinstance(b, (int, float)) and b > 0 and not math.isnan(b)):
            raise ValueError(f"energy_budget_J = {b!r}: must be > 0 (float('inf') for none)")
        if not (isinstance(self.supply_current_A, (int, float))
                and 0 < self.supply_current_A <= MAX_CURRENT_A):
            raise ValueError(f"supply_current_A = {self.supply_current_A!r}: must lie in "
                             f"(0, {MAX_CURRENT_A}] A")

    @property
    def episode_steps(self) -> int:
        return int(round(self.episode_s / self.dt))


def resolve_params(params: NeckParams | str | Path | None) -> NeckParams:
    if params is None:
        return default_params()
    if isinstance(params, NeckParams):
        return params
    if isinstance(params, (str, Path)):
        return NeckParams.load(params)
    raise ValueError(f"params must be a NeckParams, a JSON path or None, got {type(params).__name__}")


def resolve_effects(effects) -> tuple[dict[str, dict[str, float]], tuple[str, ...]]:
    """(fixed effects with parameters, names of effects sampled anew each episode)."""
    if effects is None:
        return {}, ()
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        return fx.check_effects(effects), ()
    names = tuple(effects)
    for n in names:
        if n not in fx.EFFECTS:
            raise ValueError(f"unknown effect {n!r}; known: {sorted(fx.EFFECTS)}")
    return {}, names


def validate_action(action, mode: str, n: int, single: bool) -> np.ndarray:
    """Check an action batch and return currents-to-be (N, 3) float64, or raise ValueError."""
    a = np.asarray(action)
    want = (3,) if single else (n, 3)
    if a.shape != want:
        raise ValueError(f"action must have shape {want}, got {a.shape}")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"action must be numeric, got dtype {a.dtype}")
    a = a.astype(np.float64).reshape(n, 3)
    if not np.isfinite(a).all():
        raise ValueError(f"action must be finite, got {a[~np.isfinite(a)][:3]}")
    if mode == "relay":
        if not np.isin(a, (0.0, 1.0)).all():
            raise ValueError(f"relay action must be 0 or 1 per muscle, got {a[~np.isin(a, (0.0, 1.0))][:3]}")
    elif a.min() < 0.0 or a.max() > MAX_CURRENT_A:
        raise ValueError(f"current action must lie in [0, {MAX_CURRENT_A}] A, got "
                         f"min {a.min():.4g}, max {a.max():.4g}")
    return a


@njit(cache=True)
def _sense_range(x, q_prev, dt, t_s, mount, accel_bias, gyro_bias, drift, a_sig, g_sig, T_sig,
                 rng, filt, first, t0, ramp, way, nseg, energy_left, budget, obs, reward, err,
                 target, start, stop):
    tip, dtip, rot = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
    v, w, r = np.empty(3), np.empty(3), np.empty(6)
    for i in range(start, stop):
        q = x[i, L.S_Q:L.S_Q + 3]
        imu_reading(q, q_prev[i], dt, mount[i], tip, dtip, rot, v, w, r)
        for j in range(3):
            r[j] += accel_bias[i, j] + a_sig * next_normal(rng, i)
            r[3 + j] += gyro_bias[i, j] + drift[i] * t_s[i] + g_sig * next_normal(rng, i)
        if first:
            filt[i, 0], filt[i, 1] = tilt_from_accel(r[0], r[1], r[2])
        else:
            filt[i, 0], filt[i, 1] = fuse_tilt(filt[i, 0], filt[i, 1], r[0], r[1], r[2], r[3], r[4],
                                               dt, FILTER_TAU_S)
        T1 = x[i, L.S_T] + T_sig * next_normal(rng, i)
        T2 = x[i, L.S_T + 1] + T_sig * next_normal(rng, i)
        T3 = x[i, L.S_T + 2] + T_sig * next_normal(rng, i)
        tx, ty = target_at(t_s[i], t0[i], ramp[i], way[i], nseg[i])
        target[i, 0], target[i, 1] = tx, ty
        e = tracking_error_deg(math.degrees(q[0]), math.degrees(q[1]), tx, ty)
        err[i] = e
        reward[i] = -e
        frac = energy_left[i] / budget if budget < np.inf else 1.0
        fill_observation(obs[i], filt[i, 0], filt[i, 1], T1, T2, T3, tx, ty, frac)


@njit(cache=True, parallel=True)
def _sense_parallel(x, q_prev, dt, t_s, mount, accel_bias, gyro_bias, drift, a_sig, g_sig, T_sig,
                    rng, filt, first, t0, ramp, way, nseg, energy_left, budget, obs, reward, err,
                    target):
    n = x.shape[0]
    chunks = (n + 63) // 64
    for c in prange(chunks):
        _sense_range(x, q_prev, dt, t_s, mount, accel_bias, gyro_bias, drift, a_sig, g_sig, T_sig,
                     rng, filt, first, t0, ramp, way, nseg, energy_left, budget, obs, reward, err,
                     target, c * 64, min(n, (c + 1) * 64))


class NeckTrackCore:
    """N simulated rigs on the tracking task. Not an env itself; the envs wrap it."""

    def __init__(self, num_envs: int, task: TaskConfig, params: NeckParams,
                 sensors: SensorParams, randomize: bool | Randomization, effects):
        if not (isinstance(num_envs, (int, np.integer)) and num_envs >= 1):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.n = int(num_envs)
        self.task = task
        self.params = params
        self.sensors = sensors
        self.randomization = (Randomization() if randomize is True else
                              (randomize if isinstance(randomize, Randomization) else None))
        if randomize not in (True, False, None) and not isinstance(randomize, Randomization):
            raise ValueError(f"randomize must be a bool or a Randomization, got {randomize!r}")
        self.fixed_effects, self.sampled_effects = resolve_effects(effects)
        self.base_consts = constants_from_params(params)
        n, m = self.n, task.targets.max_segments(task.episode_s)
        self.consts = np.repeat(self.base_consts, n, axis=0)
        self.x = initial_state(self.base_consts, n)
        self.q_prev = np.zeros((n, 3))
        self.energy_left = np.full(n, float(task.energy_budget_J))
        self.energy_used = np.zeros(n)
        self.out = np.zeros((n, L.N_OUT))
        self.rng_stream = np.zeros(n, dtype=np.uint64)
        self.accel_bias = np.zeros((n, 3))
        self.gyro_bias = np.zeros((n, 3))
        self.mount = np.repeat(np.eye(3)[None], n, axis=0)
        self.drift = np.zeros(n)
        self.filt = np.zeros((n, 2))
        self.t0 = np.full((n, m), np.inf)
        self.ramp = np.zeros((n, m))
        self.way = np.zeros((n, m, 2))
        self.nseg = np.ones(n, dtype=np.int64)
        self.t_index = np.zeros(n, dtype=np.int64)
        self.t_s = np.zeros(n)
        self.delay_steps = np.zeros(n, dtype=np.int64)
        self.delay_buffer: np.ndarray | None = None
        self.episode_effects: list[dict[str, dict[str, float]]] = [{} for _ in range(n)]
        self.obs = np.zeros((n, OBS_DIM), dtype=np.float32)
        self.reward = np.zeros(n)
        self.err = np.zeros(n)
        self.target = np.zeros((n, 2))
        self.currents_cmd = np.zeros((n, 3))
        self.generators = [np.random.default_rng() for _ in range(n)]
        self._any_delay = False

    # -- reset ------------------------------------------------------------------------------
    def reset(self, ids: np.ndarray, seeds: Sequence[int | None] | None) -> None:
        """Start a new episode in envs ``ids``; ``seeds`` (same length) reseed their generators."""
        spec, base = self.task.targets, self.base_consts[0]
        for k, i in enumerate(ids):
            if seeds is not None and seeds[k] is not None:
                self.generators[i] = np.random.default_rng(seeds[k])
            g = self.generators[i]
            row = base.copy()
            if self.randomization is not None:
                self.randomization.apply(row, g)
            eff = dict(self.fixed_effects)
            for name in self.sampled_effects:
                eff[name] = fx.EFFECTS[name].sample(g)
            self.episode_effects[i] = eff
            self.consts[i] = fx.apply_to_constants(row[None], eff)[0]
            self.mount[i] = fx.imu_mount(eff)
            self.drift[i] = fx.gyro_drift(eff)
            self.delay_steps[i] = int(round(fx.delay_s(eff) / self.task.dt))
            t0, ramp, way, nseg = sample_targets(spec, self.task.episode_s, g, self.t0.shape[1])
            self.t0[i], self.ramp[i], self.way[i], self.nseg[i] = t0, ramp, way, nseg
            s = self.sensors
            self.accel_bias[i] = g.normal(0.0, s.accel_bias_g, 3) if s.accel_bias_g > 0 else 0.0
            self.gyro_bias[i] = g.normal(0.0, s.gyro_bias_dps, 3) if s.gyro_bias_dps > 0 else 0.0
            self.rng_stream[i] = np.uint64(g.integers(0, 2**63))
        ids = np.asarray(ids, dtype=np.int64)
        self.x[ids] = initial_state(self.consts[ids])
        self.q_prev[ids] = 0.0
        self.energy_left[ids] = self.task.energy_budget_J
        self.energy_used[ids] = 0.0
        self.t_index[ids] = 0
        self.t_s[ids] = 0.0
        self.out[ids] = 0.0
        self.currents_cmd[ids] = 0.0
        self._any_delay = bool(self.delay_steps.any())
        if self._any_delay:
            depth = int(self.delay_steps.max()) + 1
            if self.delay_buffer is None or self.delay_buffer.shape[1] < depth:
                self.delay_buffer = np.zeros((self.n, depth, 3))
            self.delay_buffer[ids] = 0.0
        self._run_sense(first=True, ids=ids)

    # -- step -------------------------------------------------------------------------------
    def step(self, currents: np.ndarray) -> None:
        """Advance all envs by one control period with commanded currents (N, 3) in amperes."""
        self.currents_cmd = currents
        applied = currents
        if self._any_delay:
            buf = self.delay_buffer
            slot = self.t_index % buf.shape[1]
            rows = np.arange(self.n)
            buf[rows, slot] = currents
            applied = buf[rows, (self.t_index - self.delay_steps) % buf.shape[1]]
            applied = np.where((self.t_index >= self.delay_steps)[:, None], applied, 0.0)
        np.copyto(self.q_prev, self.x[:, L.S_Q:L.S_Q + 3])
        step_inplace(self.consts, self.x, np.ascontiguousarray(applied), self.task.dt, 1,
                     self.energy_left, self.out)
        self.energy_used += self.out[:, L.O_ENERGY:L.O_ENERGY + 3].sum(axis=1)
        self.t_index += 1
        self.t_s = self.t_index * self.task.dt
        self._run_sense(first=False, ids=None)

    def _run_sense(self, first: bool, ids: np.ndarray | None) -> None:
        """Sensors, target, reward and observation for all envs, or only ``ids``."""
        s = self.sensors
        args = (self.x, self.q_prev, self.task.dt, self.t_s, self.mount, self.accel_bias,
                self.gyro_bias, self.drift, s.accel_noise_g, s.gyro_noise_dps,
                s.temperature_noise_C, self.rng_stream, self.filt, first, self.t0, self.ramp,
                self.way, self.nseg, self.energy_left, float(self.task.energy_budget_J),
                self.obs, self.reward, self.err, self.target)
        if ids is None or len(ids) == self.n:
            if self.n >= PARALLEL_FROM:
                _sense_parallel(*args)
            else:
                _sense_range(*args, 0, self.n)
        else:
            for i in ids:
                _sense_range(*args, int(i), int(i) + 1)

    # -- reporting --------------------------------------------------------------------------
    @property
    def truncated(self) -> np.ndarray:
        return self.t_index >= self.task.episode_steps

    def theta_phi_deg(self) -> tuple[np.ndarray, np.ndarray]:
        return self.out[:, L.O_THETA].copy(), self.out[:, L.O_PHI].copy()

    def temperatures_C(self) -> np.ndarray:
        return self.x[:, L.S_T:L.S_T + 3].copy()

    def currents_A(self) -> np.ndarray:
        return self.out[:, L.O_CURRENT:L.O_CURRENT + 3].copy()
