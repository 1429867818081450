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
from numba import prange

from ..physics.compile import jit

from .. import effects as fx
from ..observation import FILTER_TAU_S, OBS_DIM, fill_observation, fuse_tilt, tilt_from_accel
from ..params import NeckParams, default_params
from ..physics import layout as L
from ..physics.plant import (PARALLEL_FROM, _advance_rig, constants_from_params, initial_state,
                             refresh_derived)
from ..sensors import SensorParams, imu_reading, next_normal
from ..targets import TargetSpec, sample_targets, target_at, tracking_error_deg

ACTION_MODES = ("current", "relay")
MAX_CURRENT_A = 8.0
DEFAULT_DT_S = 0.05
DEFAULT_EPISODE_S = 60.0
DEFAULT_SUPPLY_A = 7.0  # calibrated Table 1: a 5 s pulse at 7 A reaches ~24 deg (task range)
DEFAULT_BUDGET_J = 1500.0  # see README "Energy budget"
# Over-temperature cut, as the rig firmware does with thermistors fitted: overheated Flexinol
# loses its trained shape. 160 C is above the ~90-150 C a controller needs for the target range.
DEFAULT_CUTOFF_C = 160.0


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
    dt: float = DEFAULT_DT_S  # control period, s; one plant step per control step
    episode_s: float = DEFAULT_EPISODE_S
    energy_budget_J: float = DEFAULT_BUDGET_J
    supply_current_A: float = DEFAULT_SUPPLY_A
    cutoff_C: float = DEFAULT_CUTOFF_C  # a muscle's current is cut while its spring is hotter
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
        if not (isinstance(self.cutoff_C, (int, float)) and self.cutoff_C > 40):
            raise ValueError(f"cutoff_C = {self.cutoff_C!r}: must be > 40 C (float('inf') for none)")
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
    """Check an action (batch) and return it as (N, 3) float64, or raise ValueError naming why."""
    a = np.asarray(action)
    want = (3,) if single else (n, 3)
    if a.shape != want:
        raise ValueError(f"action must have shape {want}, got {a.shape}")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"action must be numeric, got dtype {a.dtype}")
    a = np.asarray(a, dtype=np.float64).reshape(n, 3)
    code = check_action(a, mode == "relay", MAX_CURRENT_A)
    if code == 1:
        raise ValueError(f"action must be finite, got {a[~np.isfinite(a)][:3]}")
    if code == 2:
        raise ValueError(f"relay action must be 0 or 1 per muscle, got "
                         f"{a[~np.isin(a, (0.0, 1.0))][:3]}")
    if code == 3:
        raise ValueError(f"current action must lie in [0, {MAX_CURRENT_A}] A, got "
                         f"min {a.min():.4g}, max {a.max():.4g}")
    return a


# Per-env auxiliary columns (besides the plant state): host-side bookkeeping and sensors.
A_QPREV = 0  # 0..2: pose before the step (for the gyro)
A_LEFT = 3  # energy budget left, J
A_USED = 4  # energy used this episode, J
A_TIDX = 5  # steps taken this episode
A_TS = 6  # time in the episode, s
A_FILT = 7  # 7..8: complementary-filter tilt vector, deg
A_ABIAS = 9  # 9..11: accelerometer bias, g
A_GBIAS = 12  # 12..14: gyro bias, deg/s
A_DRIFT = 15  # gyro bias growth, deg/s per s
A_TARGET = 16  # 16..17: target tilt vector, deg
A_ERR = 18  # tracking error, deg
A_REWARD = 19
A_DELAY = 20  # actuation delay, steps
A_NSEG = 21  # target segments in use
A_TTHETA = 22  # target theta, deg
A_TPHI = 23  # target phi, deg in [0, 360)
N_AUX = 24


@jit
def _rows(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget, a_sig,
          g_sig, T_sig, physics, first, start, stop):
    """Advance (if ``physics``) and observe envs start..stop. One compiled pass per env."""
    tip, dtip, rot = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
    offset, unit, ext = np.empty((3, 3)), np.empty((3, 2, 3)), np.empty((3, 2))
    forces, qf, fmus = np.empty((3, 2)), np.empty(3), np.empty((3, 3))
    amps, temps, applied = np.empty(3), np.empty(3), np.empty(3)
    v, w, r = np.empty(3), np.empty(3), np.empty(6)
    shared = consts.shape[0] == 1
    for i in range(start, stop):
        c = consts[0] if shared else consts[i]
        xi_row, a = x[i], aux[i]
        if physics:
            d = int(a[A_DELAY])
            tix = int(a[A_TIDX])
            if d > 0:
                depth = delay_buf.shape[1]
                for k in range(3):
                    delay_buf[i, tix % depth, k] = cur[i, k]
                    applied[k] = delay_buf[i, (tix - d) % depth, k] if tix >= d else 0.0
            else:
                for k in range(3):
                    applied[k] = cur[i, k]
            for k in range(3):
                a[A_QPREV + k] = xi_row[L.S_Q + k]
            a[A_LEFT] = _advance_rig(c, xi_row, applied, dt, 1, a[A_LEFT], out[i], tip, dtip,
                                     rot, offset, unit, ext, forces, qf, fmus, amps, temps)
            a[A_USED] += out[i, L.O_ENERGY] + out[i, L.O_ENERGY + 1] + out[i, L.O_ENERGY + 2]
            a[A_TIDX] = tix + 1
            a[A_TS] = (tix + 1) * dt
        # Sensors: IMU (bias, noise, growing gyro bias) -> rig tilt pipeline; thermistors.
        q = xi_row[L.S_Q:L.S_Q + 3]
        imu_reading(q, a[A_QPREV:A_QPREV + 3], dt, mount[i], tip, dtip, rot, v, w, r)
        n0, n1, n2 = next_normal(rng, i), next_normal(rng, i), next_normal(rng, i)
        n3, n4 = next_normal(rng, i), next_normal(rng, i)
        n5, n6, n7 = next_normal(rng, i), next_normal(rng, i), next_normal(rng, i)
        drift = a[A_DRIFT] * a[A_TS]
        ax = r[0] + a[A_ABIAS] + a_sig * n0
        ay = r[1] + a[A_ABIAS + 1] + a_sig * n1
        az = r[2] + a[A_ABIAS + 2] + a_sig * n2
        gx = r[3] + a[A_GBIAS] + drift + g_sig * n3
        gy = r[4] + a[A_GBIAS + 1] + drift + g_sig * n4
        if first:
            fx_, fy_ = tilt_from_accel(ax, ay, az)
        else:
            fx_, fy_ = fuse_tilt(a[A_FILT], a[A_FILT + 1], ax, ay, az, gx, gy, dt, FILTER_TAU_S)
        a[A_FILT], a[A_FILT + 1] = fx_, fy_
        tx, ty = target_at(a[A_TS], targets[i, :, 0], targets[i, :, 1], targets[i, :, 2:4],
                           int(a[A_NSEG]))
        a[A_TARGET], a[A_TARGET + 1] = tx, ty
        a[A_TTHETA] = math.sqrt(tx * tx + ty * ty)
        a[A_TPHI] = math.degrees(math.atan2(ty, tx)) % 360.0
        e = tracking_error_deg(math.degrees(q[0]), math.degrees(q[1]), tx, ty)
        a[A_ERR] = e
        a[A_REWARD] = -e
        frac = a[A_LEFT] / budget if budget < np.inf else 1.0
        fill_observation(obs[i], fx_, fy_, xi_row[L.S_T] + T_sig * n5,
                         xi_row[L.S_T + 1] + T_sig * n6, xi_row[L.S_T + 2] + T_sig * n7,
                         tx, ty, frac)


@jit(parallel=True)
def _rows_parallel(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget,
                   a_sig, g_sig, T_sig, physics, first):
    n = x.shape[0]
    chunks = (n + 63) // 64
    for ch in prange(chunks):
        _rows(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget, a_sig,
              g_sig, T_sig, physics, first, ch * 64, min(n, (ch + 1) * 64))


@jit
def check_action(a, relay, max_current):
    """0 if the (N, 3) float64 action is valid, else 1 non-finite, 2 not 0/1, 3 out of range."""
    for i in range(a.shape[0]):
        for k in range(3):
            v = a[i, k]
            if not math.isfinite(v):
                return 1
            if relay:
                if v != 0.0 and v != 1.0:
                    return 2
            elif v < 0.0 or v > max_current:
                return 3
    return 0


class NeckTrackCore:
    """N simulated rigs on the tracking task. Not an env itself; the envs wrap it."""

    def __init__(self, num_envs: int, task: TaskConfig, params: NeckParams,
                 sensors: SensorParams, randomize: bool | Randomization, effects):
        if not (isinstance(num_envs, (int, np.integer)) and num_envs >= 1):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if randomize not in (True, False, None) and not isinstance(randomize, Randomization):
            raise ValueError(f"randomize must be a bool or a Randomization, got {randomize!r}")
        self.n = n = int(num_envs)
        self.task = task
        self.params = params
        self.sensors = sensors
        self.randomization = (Randomization() if randomize is True else
                              (randomize if isinstance(randomize, Randomization) else None))
        self.fixed_effects, self.sampled_effects = resolve_effects(effects)
        self.base_consts = constants_from_params(params)
        self.base_consts[:, L.CUTOFF_C] = task.cutoff_C
        m = task.targets.max_segments(task.episode_s)
        self.consts = np.repeat(self.base_consts, n, axis=0)
        self.x = initial_state(self.base_consts, n)
        self.aux = np.zeros((n, N_AUX))
        self.out = np.zeros((n, L.N_OUT))
        self.rng_stream = np.zeros(n, dtype=np.uint64)
        self.mount = np.repeat(np.eye(3)[None], n, axis=0)
        self.targets = np.zeros((n, m, 4))
        self.delay_buffer = np.zeros((n, 1, 3))
        self.obs = np.zeros((n, OBS_DIM), dtype=np.float32)
        self.episode_effects: list[dict[str, dict[str, float]]] = [{} for _ in range(n)]
        self.generators = [np.random.default_rng() for _ in range(n)]
        self._budget = float(task.energy_budget_J)
        self._parallel = n >= PARALLEL_FROM
        # Every env on the same plant: let the kernel share one constants row (less memory
        # traffic at large N). Randomization or plant effects give each env its own row.
        self._shared_consts = (self.randomization is None and not self.sampled_effects
                               and not any(fx.EFFECTS[e].kind == "plant" for e in self.fixed_effects))

    # -- reset ------------------------------------------------------------------------------
    def reset(self, ids: np.ndarray, seeds: Sequence[int | None] | None) -> None:
        """Start a new episode in envs ``ids``; ``seeds`` (same length) reseed their generators."""
        spec, base, s = self.task.targets, self.base_consts[0], self.sensors
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
            refresh_derived(self.consts[i:i + 1])
            self.mount[i] = fx.imu_mount(eff)
            t0, ramp, way, nseg = sample_targets(spec, self.task.episode_s, g, self.targets.shape[1])
            self.targets[i, :, 0], self.targets[i, :, 1], self.targets[i, :, 2:4] = t0, ramp, way
            a = self.aux[i]
            a[:] = 0.0
            a[A_LEFT] = self._budget
            a[A_NSEG] = nseg
            a[A_DRIFT] = fx.gyro_drift(eff)
            a[A_DELAY] = int(round(fx.delay_s(eff) / self.task.dt))
            a[A_ABIAS:A_ABIAS + 3] = g.normal(0.0, s.accel_bias_g, 3) if s.accel_bias_g > 0 else 0.0
            a[A_GBIAS:A_GBIAS + 3] = g.normal(0.0, s.gyro_bias_dps, 3) if s.gyro_bias_dps > 0 else 0.0
            self.rng_stream[i] = np.uint64(g.integers(0, 2**63))
        ids = np.asarray(ids, dtype=np.int64)
        self.x[ids] = initial_state(self.consts[ids])
        self.out[ids] = 0.0
        depth = int(self.aux[:, A_DELAY].max()) + 1
        if self.delay_buffer.shape[1] < depth:
            self.delay_buffer = np.zeros((self.n, depth, 3))
        self.delay_buffer[ids] = 0.0
        if len(ids) == self.n:
            self._run(None, physics=False, first=True)
        else:
            for i in ids:
                self._run(None, physics=False, first=True, rows=(int(i), int(i) + 1))

    # -- step -------------------------------------------------------------------------------
    def step(self, currents: np.ndarray) -> None:
        """Advance all envs by one control period with commanded currents (N, 3) in amperes."""
        self._run(currents, physics=True, first=False)

    def _run(self, currents, physics: bool, first: bool, rows: tuple[int, int] | None = None) -> None:
        s = self.sensors
        cur = self.out if currents is None else currents  # unused when physics is False
        consts = self.consts[:1] if self._shared_consts else self.consts
        args = (consts, self.x, self.aux, self.out, self.rng_stream, self.mount,
                self.targets, self.obs, cur, self.delay_buffer, self.task.dt, self._budget,
                s.accel_noise_g, s.gyro_noise_dps, s.temperature_noise_C, physics, first)
        if rows is not None:
            _rows(*args, rows[0], rows[1])
        elif self._parallel:
            _rows_parallel(*args)
        else:
            _rows(*args, 0, self.n)

    # -- reporting --------------------------------------------------------------------------
    @property
    def truncated(self) -> np.ndarray:
        return self.aux[:, A_TIDX] >= self.task.episode_steps

    @property
    def reward(self) -> np.ndarray:
        return self.aux[:, A_REWARD]

    @property
    def err(self) -> np.ndarray:
        return self.aux[:, A_ERR]

    @property
    def target(self) -> np.ndarray:
        return self.aux[:, A_TARGET:A_TARGET + 2]

    @property
    def energy_used(self) -> np.ndarray:
        return self.aux[:, A_USED]

    @property
    def energy_left(self) -> np.ndarray:
        return self.aux[:, A_LEFT]
