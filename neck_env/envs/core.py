"""The batched core both NeckTrack environments run on (the single env is a core with N = 1).

It owns the arrays of N rigs (plant state, sensors, targets, budgets) and advances them with one
compiled pass per step (``_rows``, parallel over chunks of rigs from ``PARALLEL_FROM`` up). Per
rig, that pass applies the actuation delay, runs the plant's per-rig step
(``physics.plant.advance_rig``: over-temperature cut, budget, springs, backbone), the sensor
chain (``sensors.imu_measurement`` + ``imu_tilt_update``, thermistor noise), the target
(``targets.target_at``), the reward and the observation (``observation.fill_observation``).
Sharing one core is what makes a vector env's rollouts equal N single envs' rollouts with the
same seeds. The task's rules and its info keys come from ``neck_env.task``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from numba import prange

from .. import effects as fx
from ..observation import OBS_DIM, fill_observation
from ..params import NeckParams, resolve_params  # noqa: F401  (resolve_params: re-exported)
from ..actuation import FIRMWARE, FW_STATE_DIM, firmware_step
from ..physics import layout as L
from ..physics.compile import jit
from ..physics.plant import (PARALLEL_CHUNK, PARALLEL_FROM, advance_rig, constants_from_params,
                             initial_state, refresh_derived, rig_scratch)
from ..sensors import SensorParams, imu_measurement, imu_tilt_update, next_normal
from ..targets import target_at, tracking_error_deg
from ..task import budget_fraction_left, step_info, Task
# Re-exported for callers of the former home of these constants (neck_env.task defines them).
from ..task import (ACTION_MODES, CONTROL_DT_S, DEFAULT_BUDGET_J, DEFAULT_CUTOFF_C,  # noqa: F401
                    DEFAULT_EPISODE_S, DEFAULT_SUPPLY_A, MAX_CURRENT_A)


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
A_FWPHASE = 24  # actuation "firmware": the firmware clock at the episode start, ms
N_AUX = 25


@jit
def _rows(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget, a_sig,
          g_sig, T_sig, physics, first, fw, fw_lim, fw_relay, supply_A, start, stop):
    """Advance (if ``physics``) and observe envs start..stop. One compiled pass per env.
    ``fw`` (N, 3, FW_STATE_DIM) is the firmware state (actuation "firmware"; shape (0, 3, ..)
    for "ideal")."""
    scratch = rig_scratch()
    command = np.empty(3)
    step_ms = int(round(dt * 1000.0))
    firmware = fw.shape[0] > 0
    # the IMU's kinematics scratch is the plant's (both recompute it before use)
    sense = (scratch[0], scratch[1], scratch[2], np.empty(3), np.empty(3), np.empty(6))
    applied, meas = np.empty(3), np.empty(5)
    a_noise, g_noise = np.empty(3), np.empty(2)
    shared = consts.shape[0] == 1
    for i in range(start, stop):
        c = consts[0] if shared else consts[i]
        xi_row, a = x[i], aux[i]
        if physics:
            d = int(a[A_DELAY])
            tix = int(a[A_TIDX])
            for k in range(3):
                command[k] = cur[i, k]
            if firmware:
                # the host's over-temperature cut (HardwareNeckEnv.step), then the firmware
                for k in range(3):
                    if xi_row[L.S_T + k] >= c[L.CUTOFF_C]:
                        command[k] = 0.0
                firmware_step(fw[i], a[A_FWPHASE] + tix * step_ms, command, fw_relay,
                              supply_A, step_ms, fw_lim, command)
            if d > 0:
                depth = delay_buf.shape[1]
                for k in range(3):
                    delay_buf[i, tix % depth, k] = command[k]
                    applied[k] = delay_buf[i, (tix - d) % depth, k] if tix >= d else 0.0
            else:
                for k in range(3):
                    applied[k] = command[k]
            for k in range(3):
                a[A_QPREV + k] = xi_row[L.S_Q + k]
            a[A_LEFT] = advance_rig(c, xi_row, applied, dt, 1, a[A_LEFT], out[i], scratch)
            a[A_USED] += out[i, L.O_ENERGY] + out[i, L.O_ENERGY + 1] + out[i, L.O_ENERGY + 2]
            a[A_TIDX] = tix + 1
            a[A_TS] = (tix + 1) * dt
        # Sensors: IMU (bias, noise, growing gyro bias) -> rig tilt pipeline; thermistors.
        for k in range(3):
            a_noise[k] = a_sig * next_normal(rng, i)
        for k in range(2):
            g_noise[k] = g_sig * next_normal(rng, i)
        n5, n6, n7 = next_normal(rng, i), next_normal(rng, i), next_normal(rng, i)
        q = xi_row[L.S_Q:L.S_Q + 3]
        imu_measurement(q, a[A_QPREV:A_QPREV + 3], dt, mount[i], a[A_ABIAS:A_ABIAS + 3],
                        a[A_GBIAS:A_GBIAS + 3], a[A_DRIFT] * a[A_TS], a_noise, g_noise, sense,
                        meas)
        fx_, fy_ = imu_tilt_update(a[A_FILT], a[A_FILT + 1], meas, dt, first)
        a[A_FILT], a[A_FILT + 1] = fx_, fy_
        tx, ty = target_at(a[A_TS], targets[i, :, 0], targets[i, :, 1], targets[i, :, 2:4],
                           int(a[A_NSEG]))
        a[A_TARGET], a[A_TARGET + 1] = tx, ty
        a[A_TTHETA] = math.sqrt(tx * tx + ty * ty)
        a[A_TPHI] = math.degrees(math.atan2(ty, tx)) % 360.0
        e = tracking_error_deg(math.degrees(q[0]), math.degrees(q[1]), tx, ty)
        a[A_ERR] = e
        a[A_REWARD] = -e
        fill_observation(obs[i], fx_, fy_, xi_row[L.S_T] + T_sig * n5,
                         xi_row[L.S_T + 1] + T_sig * n6, xi_row[L.S_T + 2] + T_sig * n7,
                         tx, ty, budget_fraction_left(a[A_LEFT], budget))


@jit(parallel=True)
def _rows_parallel(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget,
                   a_sig, g_sig, T_sig, physics, first, fw, fw_lim, fw_relay, supply_A):
    n = x.shape[0]
    chunks = (n + PARALLEL_CHUNK - 1) // PARALLEL_CHUNK
    for ch in prange(chunks):
        _rows(consts, x, aux, out, rng, mount, targets, obs, cur, delay_buf, dt, budget, a_sig,
              g_sig, T_sig, physics, first, fw, fw_lim, fw_relay, supply_A, ch * PARALLEL_CHUNK,
              min(n, (ch + 1) * PARALLEL_CHUNK))


class NeckTrackCore:
    """N simulated rigs on the tracking task. Not an env itself; the envs wrap it."""

    def __init__(self, num_envs: int, task: Task, params: NeckParams,
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
        m = task.max_target_segments()
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
        self.firmware = task.actuation == "firmware"
        self.fw_state = np.zeros((n if self.firmware else 0, 3, FW_STATE_DIM))
        self._fw_lim = FIRMWARE.as_array()
        self.generators = [np.random.default_rng() for _ in range(n)]
        self._budget = float(task.energy_budget_J)
        self._episode_steps = task.episode_steps
        self._parallel = n >= PARALLEL_FROM
        # Every env on the same plant: let the kernel share one constants row (less memory
        # traffic at large N). Randomization or plant effects give each env its own row.
        self._shared_consts = (self.randomization is None and not self.sampled_effects
                               and not any(fx.EFFECTS[e].kind == "plant" for e in self.fixed_effects))

    # -- reset ------------------------------------------------------------------------------
    def reset(self, ids: np.ndarray, seeds: Sequence[int | None] | None) -> None:
        """Start a new episode in envs ``ids``; ``seeds`` (same length) reseed their generators."""
        base, s = self.base_consts[0], self.sensors
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
            t0, ramp, way, nseg = self.task.sample_targets(g, self.targets.shape[1])
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
            if self.firmware:
                # where in its duty window the firmware's clock is when the episode starts
                # (drawn last: "ideal" envs keep v0's streams)
                a[A_FWPHASE] = float(g.integers(0, FIRMWARE.duty_window_ms))
                self.fw_state[i] = 0.0
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
                s.accel_noise_g, s.gyro_noise_dps, s.temperature_noise_C, physics, first,
                self.fw_state, self._fw_lim, self.task.action_mode == "relay",
                self.task.supply_current_A)
        if rows is not None:
            _rows(*args, rows[0], rows[1])
        elif self._parallel:
            _rows_parallel(*args)
        else:
            _rows(*args, 0, self.n)

    # -- reporting --------------------------------------------------------------------------
    @property
    def truncated(self) -> np.ndarray:
        return self.aux[:, A_TIDX] >= self._episode_steps

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

    # -- named views (the info of the envs) ------------------------------------------------
    @property
    def theta_deg(self) -> np.ndarray:
        return self.out[:, L.O_THETA]

    @property
    def phi_deg(self) -> np.ndarray:
        return self.out[:, L.O_PHI]

    @property
    def temperatures_C(self) -> np.ndarray:
        return self.x[:, L.S_T:L.S_T + 3]

    @property
    def pose_rad(self) -> np.ndarray:
        """Bend b_x, b_y and twist (rad) of each env (N, 3): the pose an IMU on the head reads."""
        return self.x[:, L.S_Q:L.S_Q + 3]

    @property
    def currents_A(self) -> np.ndarray:
        return self.out[:, L.O_CURRENT:L.O_CURRENT + 3]

    @property
    def target_theta_deg(self) -> np.ndarray:
        return self.aux[:, A_TTHETA]

    @property
    def target_phi_deg(self) -> np.ndarray:
        return self.aux[:, A_TPHI]

    def info(self, i: int | None = None) -> dict[str, Any]:
        """The step ``info`` of env ``i`` (Python scalars, fresh arrays) or of all envs (fresh
        arrays: nothing a caller keeps aliases the core's buffers)."""
        if i is None:
            return step_info(theta_deg=self.theta_deg.copy(), phi_deg=self.phi_deg.copy(),
                             temperatures_C=self.temperatures_C.copy(),
                             energy_J=self.energy_used.copy(), currents_A=self.currents_A.copy(),
                             tracking_error_deg=self.err.copy(),
                             target_theta_deg=self.target_theta_deg.copy(),
                             target_phi_deg=self.target_phi_deg.copy(),
                             energy_left_J=self.energy_left.copy())
        # one env (the single env's every step): two row conversions instead of nine lookups
        out, a = self.out[i].tolist(), self.aux[i].tolist()
        return step_info(theta_deg=out[L.O_THETA], phi_deg=out[L.O_PHI],
                         temperatures_C=self.x[i, L.S_T:L.S_T + 3].copy(), energy_J=a[A_USED],
                         currents_A=self.out[i, L.O_CURRENT:L.O_CURRENT + 3].copy(),
                         tracking_error_deg=a[A_ERR], target_theta_deg=a[A_TTHETA],
                         target_phi_deg=a[A_TPHI], energy_left_J=a[A_LEFT])

    def episode_over(self, i: int) -> bool:
        """Env ``i`` has run ``episode_s`` (it is truncated)."""
        return self.aux[i, A_TIDX] >= self._episode_steps
