"""``HardwareNeckEnv``: the NeckTrack task on the physical neck, over the firmware's serial link.

A policy or controller written against ``NeckTrack-v0`` runs here unchanged: same action and
observation spaces, the observation built by the same code (``neck_env.observation``: the
IMU's complementary filter, ``fill_observation``), the same targets (``neck_env.targets``),
budget and over-temperature rules. What differs is where the numbers come from (table below),
and that time is real: each ``step`` lasts ``dt`` of wall time.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from ..experiments import REST, RestCriterion
from ..observation import FILTER_TAU_S, fill_observation, fuse_tilt, tilt_angles_deg, tilt_from_accel
from ..params import NeckParams, resolve_params
from ..recording import TEMPERATURE_COLUMNS, RecordingWriter, write_meta
from ..targets import target_at, tracking_error_deg
from ..task import Task, step_info
from . import protocol as P
from .errors import RigFirmwareReset, RigNotAtRest
from .link import RigError, RigLink, RigRefused, RigTimeout
from .memory import RigMemory
from .thermal_estimate import ThermalEstimate

__all__ = ["HardwareNeckEnv", "RECORD_COLUMNS", "RestResult"]

#: Columns of a rig recording: the required ones (docs/recording-format.md) first, then what the rig adds.
RECORD_COLUMNS = ("t", "i1", "i2", "i3", "theta_deg", "phi_deg",
                  "T1_est", "T2_est", "T3_est", "ax", "ay", "az", "gx", "gy", "gz",
                  "relays", "faults", "target_theta_deg", "target_phi_deg", "t_mcu_ms")
TELEMETRY_TIMEOUT_S = 0.3  # no telemetry for this long while running: the link is dead
FIRST_SAMPLE_TIMEOUT_S = 1.0
MEMORY_SAVE_PERIOD_S = 1.0  # a killed host loses at most this much of the springs' history


@dataclass(frozen=True)
class RestResult:
    """Outcome of a wait for rest (``HardwareNeckEnv.wait_for_rest``)."""

    at_rest: bool
    waited_s: float
    hottest_excess_K: float  # hottest spring above ambient at the end (thermistor or estimate)
    tilt_off_deg: float  # tilt from the rest reading (or from the window's start when unknown)
    rest_tilt_deg: tuple[float, float] | None  # the tilt vector held at rest (mean of the window)
    temperature_source: str
    # at rest off the rest reading: springs cold, the tilt not moving for ``RestCriterion.stuck_s``
    # (the backbone holds the neck bent: stiction)
    stuck: bool = False

    def describe(self, criterion: RestCriterion = REST) -> str:
        if self.stuck:
            return (f"springs cold ({self.hottest_excess_K:+.1f} K from ambient, "
                    f"{self.temperature_source}) and the neck stopped {self.tilt_off_deg:.2f} deg "
                    f"from the rest reading, not moving for {criterion.stuck_s:g} s: the backbone "
                    f"holds it there (stiction, backbone_friction's dead band)")
        return (f"hottest spring {self.hottest_excess_K:+.1f} K from ambient (rest: within "
                f"{criterion.temperature_K:g} K, {self.temperature_source}), tilt "
                f"{self.tilt_off_deg:.2f} deg from the rest reading (rest: within "
                f"{criterion.tilt_deg:g} deg, held {criterion.settle_s:g} s)")


def _warm_up_compiled(estimate: ThermalEstimate) -> None:
    """Compile (or load from numba's cache) every kernel the run loop and the telemetry thread
    use, before any telemetry streams. Compiling holds the GIL for seconds on a fresh install:
    during an episode that would starve the reader thread and trip the telemetry timeout."""
    fuse_tilt(0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.01, FILTER_TAU_S)
    tilt_from_accel(0.0, 0.0, 1.0)
    fill_observation(np.empty(8, np.float32), 0.0, 0.0, 25.0, 25.0, 25.0, 0.0, 0.0, 1.0)
    target_at(0.0, np.zeros(1), np.zeros(1), np.zeros((1, 2)), 1)
    tracking_error_deg(0.0, 0.0, 0.0, 0.0)
    task = Task()
    task.currents_A(np.zeros(3))
    task.cut_hot(np.zeros(3), np.zeros(3))
    task.budget_energy_scale(1.0, 1.0)
    task.budget_fraction_left(1.0)
    estimate.warm_up()


def thermistor_columns(mask: int) -> list[tuple[int, str]]:
    """(muscle index, column) of the fitted thermistors: ``Tk`` for each fitted one (the
    recording format reads any of T1..T3; a reading that fails, open or shorted, is an empty
    cell)."""
    return [(k, TEMPERATURE_COLUMNS[k]) for k in range(3) if mask >> k & 1]


class HardwareNeckEnv(gym.Env):
    """NeckTrack on the physical neck (Arduino UNO firmware, ``firmware/``).

    ## Action space (as ``NeckTrack-v0``)

    | action_mode | space | what the rig does |
    |---|---|---|
    | `"current"` (default) | `Box(0, 8, (3,), float32)`, A | per-muscle duty `(I / I_s)^2` of the supply current `I_s` (time-proportional switching in the firmware, 1 s window): the same mean Joule heat as a steady `I`. The firmware caps duty at 80 %, so the largest steady-equivalent current is `0.89 I_s` |
    | `"relay"` | `MultiBinary(3)` | relay k on: `I_s` flows (firmware caps: 10 s continuous on-time, sustained-duty limiter) |

    **Which simulation matches the rig:** `actuation="firmware"` (``neck_env.actuation``; the
    default of ``NeckTrack-v1``) simulates exactly this: the duty command, the firmware's 1 s
    windows and 80 % cap, and its on-time cap and sustained-duty limiter in relay mode. A policy
    trained with `actuation="ideal"` (``NeckTrack-v0``) assumed steady currents up to 8 A that
    the rig does not deliver. The rig does the same whatever the task's `actuation` says
    (``HardwareNeckEnv.ACTUATION``).

    Actions are checked, clipped and scaled by the same `neck_env.task.Task` as in simulation;
    invalid ones (NaN/inf, wrong shape, relay values other than 0/1) raise `ValueError` after the
    relays are commanded off.

    ## Observation space (as ``NeckTrack-v0``, built by ``neck_env.observation``)

    | index | observation | on the rig |
    |---|---|---|
    | 0, 1 | head tilt vector, deg | MPU6050 accelerometer + gyro at the telemetry rate (100 Hz), the simulator's complementary filter |
    | 2-4 | spring temperatures, deg C | NTC thermistors where fitted, else the host's estimate from the commanded currents (``ThermalEstimate``) |
    | 5, 6 | target tilt vector, deg | ``neck_env.targets``, seeded by ``reset(seed=...)`` |
    | 7 | energy budget left, fraction | host accounting: commanded on-time x `I_s^2 R(xi)` with the model's resistance |

    ## Rewards

    `-e`, `e` the distance (deg) between the **measured** tilt vector and the target's (the rig
    has no ground truth; in simulation the true tilt is used).

    ## Starting state

    `reset` switches everything off and, unless `cooldown_s = 0`, waits (relays off) until
    the neck is at rest (``wait_for_rest``: the springs within `cooldown_margin_C` of ambient
    -- thermistors, else the estimate --, and the tilt steady, or back at a given rest reading,
    for ``REST.settle_s``) or `cooldown_s` has passed (then it goes on, or with
    ``options={"require_rest": True}`` raises ``RigNotAtRest``). A neck that stops off a given
    rest reading with its springs cold, not moving for ``REST.stuck_s``, is at rest there
    (``RestResult.stuck``: a backbone with stiction holds it bent; the episode starts from
    there, and ``say`` tells the user to nudge it upright). The estimate remembers the
    springs across processes (``neck_env.rig.memory``): a second command right after a first
    waits for the springs the first one heated. The target is upright for the first 2 s.

    ## Episode end

    | condition | result |
    |---|---|
    | `episode_s` elapsed (`episode_s / dt` steps) | `truncated = True` |
    | the budget is spent | actuation cut, the episode goes on (as in simulation); it is charged from the relays' telemetry, so a host stalled with a relay on is charged what passed meanwhile and may overdraw by that much: at most the firmware's 250 ms heartbeat, which then cuts the relay |
    | a spring at or above `cutoff_C` | that muscle is held off until it is below (host side, on the observed temperature); with thermistors fitted the firmware cuts at the same `cutoff_C` (sent with `CONFIG`, at most its own maximum of ~167 C) |
    | IMU missing or failing, link lost or silent, firmware rejects a command | relays off, `RigError` raised (`RigRefused`, `RigLinkLost`, `RigTimeout`) |
    | Ctrl-C (`KeyboardInterrupt`) during a step | relays off, recording flushed, re-raised |

    ## Info

    The keys of ``NeckTrack-v0`` (`theta_deg`, `phi_deg` -- measured here --, `temperatures_C`,
    `energy_J`, `currents_A` -- the RMS commanded current over the step --, `tracking_error_deg`,
    `target_theta_deg`, `target_phi_deg`, `energy_left_J`, `budget_exhausted`) plus `relays`
    (pin states read back), `faults` (``protocol.Fault``), `refused` (muscles held off by a
    firmware safety hold), `late_s` (how late this step ended), `temperature_source`
    (`"thermistor"` or `"estimate"`), `recording` (path, when recording).

    ## Recording

    With `record_dir`, every episode writes `rec_NN.csv` (format: docs/recording-format.md;
    `t`, commanded `i1..i3` = `I_s` while the relay pin is on, `theta_deg`, `phi_deg`, `Tk`
    for each fitted thermistor -- empty where it reads open or shorted --; the estimate as
    `T1_est..`, raw IMU, relays, faults, target) at the
    telemetry rate, flushed at least every 0.5 s, and `meta.json`; `neck_env.gap` reads the
    folder as it is.

    ## Arguments

    `port` (device path or pyserial URL) or `link` (an open ``RigLink``); the task of
    ``NeckTrack-v0`` (``neck_env.task.Task``, as `task=` or its fields as keywords:
    `action_mode`, `dt`, `episode_s`, `energy_budget_J`, `supply_current_A` -- **set the supply
    to this current** --, `cutoff_C`, `targets`); `params` (the model for the thermal estimate
    and the energy accounting); `thermistors`
    (mask of fitted thermistors, bit k = muscle k; default none), `stream_hz` (100),
    `ambient_C` (for the estimate; default: the parameters'), `cooldown_s` (300),
    `cooldown_margin_C` (3), `record_dir`, `remember` (carry the thermal estimate across
    processes, ``neck_env.rig.memory``; default on), `say` (a callable for progress lines,
    e.g. ``print``: the waits for rest say what they wait for).
    """

    metadata = {"render_modes": []}
    #: the simulated actuation (``Task.actuation``) that matches what this env does
    ACTUATION = "firmware"

    def __init__(self, port: str | None = None, *, link: RigLink | None = None,
                 task: Task | None = None, params: NeckParams | str | None = None,
                 thermistors: int = 0, stream_hz: int = 100, ambient_C: float | None = None,
                 cooldown_s: float = 300.0, cooldown_margin_C: float = 3.0,
                 record_dir: str | Path | None = None, open_timeout: float = 4.0,
                 remember: bool = True, say: Callable[[str], None] | None = None,
                 **task_kwargs: Any) -> None:
        if (port is None) == (link is None):
            raise ValueError("give exactly one of port (device path or pyserial URL) or link")
        if task is None:
            task = Task.from_kwargs(task_kwargs)
        elif task_kwargs:
            raise TypeError(f"give the task either as task=Task(...) or as keywords, not both "
                            f"(got task and {sorted(task_kwargs)})")
        self.task = task
        if not (isinstance(thermistors, int) and 0 <= thermistors <= 7):
            raise ValueError(f"thermistors must be a bit mask 0..7 (bit k = muscle k), got {thermistors!r}")
        if not (isinstance(stream_hz, int) and 10 <= stream_hz <= 100):
            raise ValueError(f"stream_hz must be an integer in [10, 100], got {stream_hz!r}")
        if stream_hz * self.task.dt < 1.0:
            raise ValueError(f"stream_hz {stream_hz} gives less than one IMU sample per step of "
                             f"{self.task.dt} s")
        if not (cooldown_s >= 0 and cooldown_margin_C > 0):
            raise ValueError("need cooldown_s >= 0 and cooldown_margin_C > 0")
        self.params = resolve_params(params)
        self.dt = self.task.dt
        self.action_mode = self.task.action_mode
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self.thermistor_mask = thermistors
        self._thermistor_cols = thermistor_columns(thermistors)  # per telemetry row: once here
        self.stream_hz = stream_hz
        self.cooldown_s = float(cooldown_s)
        self.cooldown_margin_C = float(cooldown_margin_C)
        self.record_dir = None if record_dir is None else Path(record_dir)
        self.estimate = ThermalEstimate(self.params, ambient_C)
        _warm_up_compiled(self.estimate)
        # Wall time up to which the estimate has been advanced: the springs keep cooling
        # between episodes, whether or not anybody calls step().
        self._est_clock = time.monotonic()
        self._lock = threading.Lock()
        self._rows: list[dict[str, Any]] = []
        self._reset_telemetry_state()
        self._writer: RecordingWriter | None = None
        self._record_as: str | None = None
        self._episode_active = False
        self._closed = False
        self._boots_seen = 0
        self.recordings: list[Path] = []
        self.link = link if link is not None else RigLink(port, open_timeout=open_timeout)
        self.say = say
        self.last_rest: RestResult | None = None
        # time.monotonic() as this episode's first command went out (``schedule_s``)
        self.first_command_s: float | None = None
        self.memory = RigMemory(self.link.port) if remember else None
        self.memory_note = self.memory.restore(self.estimate) if self.memory else ""
        self._est_clock = time.monotonic()
        self._memory_saved = self._est_clock
        self.link.on_telemetry = self._on_telemetry
        try:
            self._configure()
        except BaseException:
            self.link.close()
            raise

    # -- firmware set-up ----------------------------------------------------------------------
    def _config_message(self) -> P.Config:
        """CONFIG for the fitted thermistors, with the firmware's cut at ``cutoff_C`` so the
        rig cuts where the simulator does (firmware >= 1.1; 1.0 had a fixed 110 C cut)."""
        if not self.thermistor_mask:
            return P.Config(0)
        try:
            return P.Config.for_cutoff(self.thermistor_mask, self.task.cutoff_C)
        except P.ProtocolError as exc:
            raise ValueError(f"cutoff_C = {self.task.cutoff_C} with thermistors fitted: {exc}; "
                             f"pass cutoff_C <= {P.THERM_MAX_CUT_C:.0f}") from None

    def _configure(self) -> None:
        self.link.command(P.SetRelays(0))
        self.link.command(self._config_message())
        self.link.command(P.ClearFaults())
        self.link.command(P.Stream(self.stream_hz))
        self.hello = self.link.hello

    def _reset_telemetry_state(self) -> None:
        with self._lock:
            self._tilt: tuple[float, float] | None = None
            self._last: P.Telemetry | None = None
            self._last_host_t = 0.0
            self._last_mcu_ms: int | None = None
            self._on_ms = np.zeros(3)
            self._span_ms = 0.0
            self._samples = 0

    def _drain_after_stall(self) -> None:
        """Telemetry that looks stale because this process stalled (a garbage collection, a slow
        policy, a loaded machine) rather than the link: the frames then wait in the port's
        buffer, unread. Give the reader thread up to the timeout again to drain them, so only a
        link silent for that long too, or a restarted MCU, is called silent."""
        end = time.monotonic() + TELEMETRY_TIMEOUT_S
        while len(self.link.boots) <= self._boots_seen:
            with self._lock:
                fresh = (self._last is not None
                         and time.monotonic() - self._last_host_t <= TELEMETRY_TIMEOUT_S)
            if fresh or time.monotonic() >= end:
                return
            self.link.check()
            time.sleep(0.005)

    # -- telemetry (reader thread) ------------------------------------------------------------
    def _on_telemetry(self, tm: P.Telemetry, t_host: float) -> None:
        ax, ay, az = (v / P.ACCEL_LSB_PER_G for v in tm.accel)
        gx, gy, _ = (v / P.GYRO_LSB_PER_DPS for v in tm.gyro)
        with self._lock:
            if self._last_mcu_ms is None:
                dt_ms = 0.0
                self._tilt = tilt_from_accel(ax, ay, az)
            else:
                dt_ms = float((tm.t_ms - self._last_mcu_ms) & 0xFFFFFFFF)
                if dt_ms > 1000.0:  # a gap (reset, lost frames): restart the filter
                    self._tilt = tilt_from_accel(ax, ay, az)
                    dt_ms = 0.0
                else:
                    bx, by = self._tilt if self._tilt is not None else (0.0, 0.0)
                    self._tilt = fuse_tilt(bx, by, ax, ay, az, gx, gy, dt_ms / 1000.0, FILTER_TAU_S)
                # the previous sample's relay states held over the interval
                if self._last is not None:
                    for k in range(3):
                        if self._last.relays >> k & 1:
                            self._on_ms[k] += dt_ms
            self._span_ms += dt_ms
            self._samples += 1
            self._last, self._last_host_t, self._last_mcu_ms = tm, t_host, tm.t_ms
            if self._episode_active:
                self._rows.append(self._row(tm))

    def _row(self, tm: P.Telemetry) -> dict[str, Any]:
        """A recording row (called with the lock held)."""
        th, ph = tilt_angles_deg(*self._tilt)
        tgt_th, tgt_ph = tilt_angles_deg(*self._target_now)
        Is = self.task.supply_current_A
        row = {"t": ((tm.t_ms - self._t0_mcu_ms) & 0xFFFFFFFF) / 1000.0,
               "i1": Is * (tm.relays & 1), "i2": Is * (tm.relays >> 1 & 1),
               "i3": Is * (tm.relays >> 2 & 1), "theta_deg": float(th), "phi_deg": float(ph),
               "ax": tm.accel[0], "ay": tm.accel[1], "az": tm.accel[2],
               "gx": tm.gyro[0], "gy": tm.gyro[1], "gz": tm.gyro[2],
               "relays": tm.relays, "faults": int(tm.faults),
               "target_theta_deg": float(tgt_th), "target_phi_deg": float(tgt_ph),
               "t_mcu_ms": tm.t_ms}
        T = self._T_est
        row.update({"T1_est": T[0], "T2_est": T[1], "T3_est": T[2]})
        for k, name in self._thermistor_cols:
            row[name] = P.ntc_adc_to_celsius(tm.thermistors[k])
        return row

    # -- helpers ------------------------------------------------------------------------------
    def _temperatures(self, tm: P.Telemetry | None) -> tuple[np.ndarray, str]:
        T = self.estimate.temperatures_C
        if not self.thermistor_mask or tm is None:
            return T, "estimate"
        for k in range(3):
            if self.thermistor_mask >> k & 1:
                v = P.ntc_adc_to_celsius(tm.thermistors[k])
                if math.isfinite(v):
                    T[k] = v
        return T, "thermistor" if self.thermistor_mask == 7 else "thermistor+estimate"

    def _fail(self, exc: BaseException) -> None:
        """Relays off, recording closed; called on every error path before raising."""
        self._episode_active = False
        try:
            self.link.all_off()
        finally:
            self._close_recording()
            self._remember()

    def _remember(self) -> None:
        if self.memory is not None:
            self._catch_up_estimate()
            self.memory.save(self.estimate)
            self._memory_saved = time.monotonic()

    def _check_faults(self, tm: P.Telemetry) -> None:
        if tm.faults & P.Fault.imu_any():
            names = "|".join(f.name for f in P.Fault if f & tm.faults & P.Fault.imu_any())
            raise RigRefused(f"IMU fault reported by the firmware ({names}): check the MPU6050 "
                             f"wiring (I2C on A4/A5, address 0x68); relays switched off")

    def _wait_telemetry(self, after_samples: int, timeout: float) -> P.Telemetry:
        deadline = time.monotonic() + timeout
        while True:
            self.link.check()
            with self._lock:
                if self._samples > after_samples and self._last is not None:
                    return self._last
            if time.monotonic() > deadline:
                raise RigTimeout(f"{self.link.port}: no telemetry for {timeout:.2f} s (firmware "
                                 f"reset or link stalled); relays switched off")
            time.sleep(0.005)

    def _open_recording(self) -> None:
        if self.record_dir is None:
            return
        self.record_dir.mkdir(parents=True, exist_ok=True)
        if not (self.record_dir / "meta.json").exists():
            h = self.link.hello
            write_meta(self.record_dir, {
                "ambient_C": self.estimate.ambient_C, "sample_hz": float(self.stream_hz),
                "muscle_azimuth_deg": list(self.params.muscles.azimuths_deg),
                # provenance for whoever reads the dataset later (extra keys are kept)
                "rig": {"port": self.link.port,
                        "firmware_version": ".".join(map(str, h.fw_version)) if h else None,
                        "thermistor_mask": self.thermistor_mask,
                        "temperatures": ("T1..T3: thermistors; " if self.thermistor_mask else "")
                        + "T1_est..T3_est: host thermal model on the commanded currents",
                        "currents": "i1..i3: supply setpoint while the relay pin reads on"}})
        if self._record_as is not None:
            path = self.record_dir / self._record_as
        else:
            n = len(list(self.record_dir.glob("rec_*.csv"))) + 1
            path = self.record_dir / f"rec_{n:02d}.csv"
            while path.exists():
                n += 1
                path = self.record_dir / f"rec_{n:02d}.csv"
        cols = list(RECORD_COLUMNS)
        cols[6:6] = [name for _, name in self._thermistor_cols]
        self._writer = RecordingWriter(path, cols)
        self.recordings.append(path)

    def _drain_rows(self) -> None:
        with self._lock:
            rows, self._rows = self._rows, []
        if self._writer is not None and rows:
            self._writer.write_many(rows)

    def _close_recording(self) -> None:
        try:
            self._drain_rows()
        finally:
            if self._writer is not None:
                self._writer.close()
                self._writer = None

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode (see the class docs). ``options`` (all optional):
        ``record_as`` (file name in ``record_dir`` for this episode's recording),
        ``rest_tilt_deg`` (the tilt vector read at rest: wait until the tilt is back within
        ``REST.tilt_deg`` of it), ``require_rest`` (raise ``RigNotAtRest`` instead of going on
        when the neck is not at rest after ``cooldown_s``), ``start_within_K`` (a tighter start
        than `cooldown_margin_C`: the springs within this of ambient, or no longer cooling --
        ``RestCriterion.springs_cold``; a protocol's ``Recording.start_within_K``)."""
        super().reset(seed=seed)
        self._check_open()
        self._episode_active = False
        opts = dict(options or {})
        unknown = set(opts) - {"record_as", "rest_tilt_deg", "require_rest", "start_within_K"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}")
        within = opts.get("start_within_K")
        if within is not None and not (isinstance(within, (int, float)) and within > 0):
            raise ValueError(f"start_within_K must be a positive number of kelvin, got {within!r}")
        self._record_as = opts.get("record_as")
        try:
            self._close_recording()
            if self.link.lost is not None:
                # the port vanished in an earlier episode: reopen it (USB replugged) and check
                # the firmware again; raises RigLinkLost if it is still gone
                self.link.reconnect()
            # everything again, not only relays off: an error path or an MCU restart stopped
            # the telemetry and may have forgotten the configuration
            self._configure()
            self._boots_seen = len(self.link.boots)
            tm = self._wait_telemetry(self._samples, FIRST_SAMPLE_TIMEOUT_S)
            self._check_faults(tm)
            self._cool_down(opts.get("rest_tilt_deg"), bool(opts.get("require_rest", False)),
                            within)
            # The simulated env's derivation (its np_random draws the core's seed, whose
            # Generator draws the targets): a seed gives the same targets as NeckTrack-v0.
            g = np.random.default_rng(int(self.np_random.integers(0, 2**63)))
            self._t0s, self._ramps, self._ways, self._nseg = self.task.sample_targets(g)
            self._k = 0
            self._energy_J = 0.0
            self._exhausted = False
            self._T_est = self.estimate.temperatures_C
            self._target_now = target_at(0.0, self._t0s, self._ramps, self._ways, self._nseg)
            self._open_recording()
            with self._lock:
                self._t0_mcu_ms = self._last.t_ms
                self._on_ms[:] = 0.0
                self._span_ms = 0.0
                self._rows = []
                self._episode_active = True
            self._t_start = time.monotonic()
            self.first_command_s = None
            obs, info = self._observe(np.zeros(3), tm, refused=0, late=0.0)
        except BaseException as exc:
            self._fail(exc)
            raise
        return obs, info

    def _catch_up_estimate(self) -> None:
        """Cool the estimate over the time since it was last advanced. Relays are off then:
        the env switches them off at every episode end and error, and the firmware's heartbeat
        watchdog does 250 ms after a host stops stepping."""
        now = time.monotonic()
        if now > self._est_clock:
            self.estimate.advance(np.zeros(3), now - self._est_clock)
        self._est_clock = now

    def _cool_down(self, rest_tilt_deg=None, require: bool = False,
                   start_within_K: float | None = None) -> None:
        self._catch_up_estimate()
        if self.cooldown_s <= 0:
            self.last_rest = None
            return
        # the env's margin bounds the start; a recording may ask for a colder one, which a
        # spring no longer cooling within the margin also meets (the ambient may be off)
        crit = replace(REST, temperature_K=min(self.cooldown_margin_C,
                                               start_within_K or self.cooldown_margin_C),
                       plateau_within_K=self.cooldown_margin_C, timeout_s=self.cooldown_s)
        r = self.wait_for_rest(crit, rest_tilt_deg)
        self.last_rest = r
        if r.stuck and self.say is not None:
            self.say(f"the neck is at rest off its rest reading: {r.describe(crit)}; going on "
                     f"from there (nudge the head upright to start from the rest reading)")
        if not r.at_rest and require:
            raise RigNotAtRest(f"{self.link.port}: the neck is not at rest after "
                               f"{r.waited_s:.0f} s: {r.describe(crit)}; relays off. Check the "
                               f"springs cool freely (nothing touching, no heat source) and the "
                               f"IMU has not moved on its mount")

    def wait_for_rest(self, criterion: RestCriterion = REST,
                      rest_tilt_deg: tuple[float, float] | None = None) -> RestResult:
        """Wait, relays off, until the neck is at rest or ``criterion.timeout_s`` has passed.

        At rest: every spring within ``criterion.temperature_K`` of ambient (thermistors where
        fitted, else the estimate; or no longer cooling: ``RestCriterion.springs_cold``) and
        the fused IMU tilt within ``criterion.tilt_deg`` of
        ``rest_tilt_deg`` (a tilt vector, deg) -- or, when that is not known, of the tilt at
        the start of the window (a neck still creeping back moves) -- both held for
        ``criterion.settle_s``. Also at rest, ``stuck``: the springs cold and the tilt off
        ``rest_tilt_deg`` but within ``criterion.steady_deg`` of where it stopped for
        ``criterion.stuck_s`` (a backbone with stiction holds the neck bent; waiting longer
        would not bring it back). Says how it is going every 15 s through ``say``."""
        t0 = time.monotonic()
        held_since: float | None = None
        anchor: tuple[float, float] | None = None
        acc: list[tuple[float, float]] = []
        still_since: float | None = None  # cold, off the rest reading, and not moving since
        still_at: tuple[float, float] | None = None
        still: list[tuple[float, float]] = []
        last_say = t0
        ambient = self.estimate.ambient_C
        keep_s = criterion.plateau_s + 2.0  # the history springs_cold looks at
        seen_t: collections.deque[float] = collections.deque()
        seen_excess: collections.deque[float] = collections.deque()
        while True:
            now = time.monotonic()
            self._catch_up_estimate()
            T, source = self._temperatures(self._last)
            excess = float(np.max(T - ambient))
            seen_t.append(now - t0)
            seen_excess.append(excess)
            while seen_t[-1] - seen_t[0] > keep_s:
                seen_t.popleft()
                seen_excess.popleft()
            cold = criterion.springs_cold(seen_t, seen_excess)
            with self._lock:
                tilt = self._tilt
            ref = rest_tilt_deg if rest_tilt_deg is not None else anchor
            off = (math.inf if tilt is None else 0.0 if ref is None
                   else math.hypot(tilt[0] - ref[0], tilt[1] - ref[1]))
            ok = tilt is not None and cold and off <= criterion.tilt_deg
            if ok:
                if held_since is None:
                    held_since, acc = now, []
                    if rest_tilt_deg is None:
                        anchor = tilt
                acc.append(tilt)
                if now - held_since >= criterion.settle_s:
                    mean = (float(np.mean([a[0] for a in acc])), float(np.mean([a[1] for a in acc])))
                    return RestResult(True, now - t0, excess, off, mean, source)
            else:
                held_since, anchor = None, None
            if rest_tilt_deg is not None and tilt is not None and not ok and cold:
                if still_at is None or math.hypot(tilt[0] - still_at[0],
                                                  tilt[1] - still_at[1]) > criterion.steady_deg:
                    still_since, still_at, still = now, tilt, []
                still.append(tilt)
                if now - still_since >= criterion.stuck_s:
                    mean = (float(np.mean([a[0] for a in still])), float(np.mean([a[1] for a in still])))
                    return RestResult(True, now - t0, excess, off, mean, source, stuck=True)
            else:
                still_since, still_at = None, None
            if now - t0 >= criterion.timeout_s:
                return RestResult(False, now - t0, excess, off, None, source)
            if self.say is not None and now - last_say >= 15.0:
                last_say = now
                plateau = (", or no longer cooling within "
                           f"{ambient + criterion.plateau_within_K:.1f} C"
                           if criterion.plateau_within_K > criterion.temperature_K else "")
                what = (f"hottest spring {T.max():.1f} C (rest: <= "
                        f"{ambient + criterion.temperature_K:.1f} C{plateau})"
                        if not cold else "springs at ambient")
                if rest_tilt_deg is not None and off > criterion.tilt_deg:
                    what += f", tilt {off:.1f} deg from the rest reading (rest: <= {criterion.tilt_deg:g})"
                elif rest_tilt_deg is None and not ok and cold:
                    what += ", tilt still moving"
                elif ok:
                    what += f", tilt at rest: holding {criterion.settle_s:g} s"
                self.say(f"waiting for the neck to rest: {what} -- {now - t0:.0f} s "
                         f"(gives up at {criterion.timeout_s:.0f} s)")
            self.link.keepalive()
            time.sleep(0.05)

    def schedule_s(self) -> float:
        """Where a relay schedule in real time stands for the step about to be commanded: the
        host's time since this episode's first command went out, plus half a step (the step's
        command goes out nearest that instant); 0 before the first. A schedule read at this
        time, not at (steps taken) x dt, keeps its edges on the host's clock through a stalled
        step, which the env absorbs by stretching the episode rather than sprinting."""
        if self.first_command_s is None:
            return 0.0
        return time.monotonic() - self.first_command_s + self.dt / 2

    def step(self, action):
        self._check_open()
        if not self._episode_active:
            raise RuntimeError("call reset() before step() (and after an error or the episode end)")
        try:
            return self._step(self.task.currents_A(action)[0])
        except BaseException as exc:
            self._fail(exc)
            if isinstance(exc, (RigError, ValueError, KeyboardInterrupt)):
                raise
            raise RigError(f"rig step failed, relays switched off: {exc!r}") from exc

    def _step(self, currents_A: np.ndarray):
        Is = self.task.supply_current_A
        T_now, _ = self._temperatures(self._last)
        # the task's rules, as the plant applies them in simulation: over-temperature cut, then
        # the budget (scaled so this step cannot overdraw it)
        cur = self.task.cut_hot(currents_A, T_now)
        duty = np.clip((cur / Is) ** 2, 0.0, 1.0)  # relay mode: exactly 0 or 1
        left = self.task.energy_budget_J - self._energy_J
        planned = float((duty * Is ** 2 * self.estimate.resistance_ohm()).sum() * self.dt)
        if left <= 1e-9:
            duty[:] = 0.0
            self._exhausted = True
        else:
            duty *= self.task.budget_energy_scale(planned, left)
        if self.action_mode == "relay" and not np.all((duty == 0) | (duty == 1)):
            # relays cannot pass a fraction: hold them off rather than overdraw the last step
            duty[:] = 0.0
            self._exhausted = True
        if self.first_command_s is None:  # the host clock a relay schedule is timed from
            self.first_command_s = time.monotonic()
        if self.action_mode == "relay":
            mask = int(sum(1 << k for k in range(3) if duty[k] >= 1.0))
            ack = self.link.command(P.SetRelays(mask), retries=0)
        else:
            ack = self.link.command(P.SetDuty(tuple(int(round(1000 * d)) for d in duty)), retries=0)
        # real time: end the step dt after the previous one; never sprint to catch up
        self._k += 1
        deadline = self._t_start + self._k * self.dt
        while True:
            now = time.monotonic()
            if now >= deadline:
                break
            self.link.check()
            time.sleep(min(0.005, deadline - now))
        # the wait for telemetry delayed by a stall belongs to this step: late_s says when the
        # step really ended, and the relay stayed on through it
        self._drain_after_stall()
        late = time.monotonic() - deadline
        if late > self.dt:
            self._t_start += late  # re-anchor: a slow policy stretches the episode, not the physics
        with self._lock:
            tm, age = self._last, time.monotonic() - self._last_host_t
            on_ms, span_ms = self._on_ms.copy(), self._span_ms
            self._on_ms[:] = 0.0
            self._span_ms = 0.0
        # a restarted MCU also falls silent (it streams again only once configured): name the
        # restart, the cause, before the silence it brings
        if len(self.link.boots) > self._boots_seen:
            boot = self.link.boots[-1]
            raise RigFirmwareReset(
                f"{self.link.port}: the MCU restarted mid-episode ("
                f"{'AVR watchdog: its loop hung' if boot.watchdog_reset else 'reset or brown-out'}"
                f"); its commands are lost, relays switched off")
        if tm is None or age > TELEMETRY_TIMEOUT_S:
            raise RigTimeout(f"{self.link.port}: no telemetry for {age:.2f} s; relays switched off")
        self._check_faults(tm)
        frac = on_ms / span_ms if span_ms > 0 else np.array([tm.relays >> k & 1 for k in range(3)], float)
        rms = Is * np.sqrt(np.clip(frac, 0.0, 1.0))
        # over the telemetry's own time span when there is one (a late step covers more than
        # dt of heating), then idle until now
        span_s = span_ms / 1000.0 if span_ms > 0 else self.dt
        self._energy_J += self.estimate.advance(rms, span_s)
        self._est_clock += span_s
        self._catch_up_estimate()
        if self.memory is not None and time.monotonic() - self._memory_saved >= MEMORY_SAVE_PERIOD_S:
            self._remember()
        if self._energy_J >= self.task.energy_budget_J - 1e-9:
            self._exhausted = True
        t = self._k * self.dt
        self._target_now = target_at(t, self._t0s, self._ramps, self._ways, self._nseg)
        self._T_est = self.estimate.temperatures_C
        self._drain_rows()
        obs, info = self._observe(rms, tm, refused=ack.refused_mask, late=max(late, 0.0))
        reward = -info["tracking_error_deg"]
        truncated = self._k >= self.task.episode_steps
        if truncated:
            self._episode_active = False
            self.link.command(P.SetRelays(0))
            self._close_recording()
            self._remember()
        return obs, float(reward), False, truncated, info

    def _observe(self, rms: np.ndarray, tm: P.Telemetry, refused: int, late: float):
        with self._lock:
            tx, ty = self._tilt
        T, source = self._temperatures(tm)
        gx, gy = self._target_now
        b = self.task.energy_budget_J
        left = max(b - self._energy_J, 0.0)
        obs = np.empty(8, np.float32)
        fill_observation(obs, tx, ty, T[0], T[1], T[2], gx, gy, self.task.budget_fraction_left(left))
        th, ph = tilt_angles_deg(tx, ty)
        tth, tph = tilt_angles_deg(gx, gy)
        info = step_info(theta_deg=float(th), phi_deg=float(ph), temperatures_C=T.copy(),
                         energy_J=float(self._energy_J), currents_A=np.asarray(rms, float).copy(),
                         tracking_error_deg=float(tracking_error_deg(tx, ty, gx, gy)),
                         target_theta_deg=float(tth), target_phi_deg=float(tph),
                         energy_left_J=float(left), budget_exhausted=bool(self._exhausted))
        info.update({"relays": tuple(bool(tm.relays >> k & 1) for k in range(3)),
                     "faults": P.Fault(tm.faults), "refused": int(refused), "late_s": float(late),
                     "temperature_source": source})
        if self._writer is not None:
            info["recording"] = str(self._writer.path)
        return obs, info

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("HardwareNeckEnv is closed")

    def close(self) -> None:
        """Relays off, telemetry off, recording flushed, port closed. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._episode_active = False
        try:
            self.link.close()
        finally:
            self._close_recording()
            self._remember()

    def set_episode(self, *, supply_current_A: float | None = None,
                    episode_s: float | None = None) -> None:
        """Between episodes: the bench supply was set to another current, or the next episode
        has another length (the rig's ``protocol`` command records a protocol this way on one
        link and one thermal estimate). Takes effect at the next ``reset``."""
        if self._episode_active:
            raise RuntimeError("set_episode between episodes only")
        changes: dict[str, float] = {}
        if supply_current_A is not None:
            changes["supply_current_A"] = float(supply_current_A)
        if episode_s is not None:
            changes["episode_s"] = float(episode_s)
        self.task = replace(self.task, **changes)
