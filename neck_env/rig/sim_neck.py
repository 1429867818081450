"""The emulated rig: the simulator playing the physical neck around the real firmware.

This is what ``python -m neck_env.rig emulate`` runs (:class:`EmulatedRig`), and what the HIL
tests run: a rig to try every ``rig`` command on without hardware.

:class:`SimulatedNeck` closes the loop around the real firmware running in simavr
(``neck_env.rig.simavr.SimavrHarness``): relay pin changes (time-stamped in simulated MCU time)
-> supply current through the switched muscles -> ``neck_env.physics.plant`` -> head pose ->
MPU6050 accelerometer and gyro registers (``neck_env.sensors.imu_reading``, plus white noise
and biases of ``SensorParams``) and, optionally, thermistor ADC counts. The physics clock is
the emulator's own clock, so the firmware's timing (duty windows, watchdogs) and the plant
agree whatever the emulator's speed; the plant runs ahead of that clock and queues its IMU
samples by time, so the firmware reads the sample due at its own time however late the plant's
thread is scheduled (a relay edge learnt late rewinds the plant to it); the host sees the same
serial traffic as from a real UNO.

The neck can carry the catalogue's effects (``neck_env.effects``: plant effects through
``apply_to_constants``, ``imu_misalignment`` through ``imu_mount``, ``actuation_delay`` by
applying relay edges late, ``gyro_bias_drift`` as a gyro bias growing with the emulator's
time, as the synthetic rig does through a dataset) and any ``NeckParams``; its "bench supply" current can be changed
while it runs (:attr:`SimulatedNeck.supply_current_A`; ``EmulatedRig`` reads it from a file, so
``rig protocol --supply-cmd`` can set it like a programmable supply).
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path
from typing import Mapping

import numpy as np

from .. import effects as fx
from ..params import NeckParams, default_params
from ..physics import layout as L
from ..physics.plant import constants_from_params, initial_state, step_inplace
from ..sensors import SensorParams, imu_reading
from . import protocol as P
from .simavr import HarnessError, SimavrHarness, build

__all__ = ["SimulatedNeck", "EmulatedRig"]

PLANT_DT_US = 10_000
PLANT_DT_S = PLANT_DT_US / 1e6
# The plant runs this far ahead of the MCU's clock and queues its IMU samples (``IMU_AT``): the
# firmware reads the sample due at its own time even when the OS schedules the plant's thread
# late. Serving only the latest value, a late thread handed the firmware a tilt as old as its
# lateness -- an actuation delay the rig does not have, which one CI run named on the
# effect-free emulated rig; holding the MCU for the plant instead (tried) stalled it into the
# host's reply deadlines on a loaded machine.
AHEAD_US = 250_000
IMU_AT_BATCH = 40  # samples per IMU_AT line (the harness reads lines of up to 4 KiB)


def _int16(v: float) -> int:
    return int(max(-32768, min(32767, round(v))))


class SimulatedNeck:
    """Run the plant against the harness's relay pins in a background thread.

    ``supply_current_A``: what flows through a muscle while its relay pin is on.
    ``thermistors``: mask of muscles whose spring temperature is served on A0-A2.
    ``sensors=None`` gives a noise-free IMU; ``seed`` seeds noise and biases.
    """

    def __init__(self, harness: SimavrHarness, supply_current_A: float = 7.0,
                 params: NeckParams | None = None, sensors: SensorParams | None = SensorParams(),
                 effects: Mapping[str, Mapping[str, float]] | None = None, thermistors: int = 0,
                 seed: int = 0, period_s: float = 0.005) -> None:
        self.h = harness
        self.supply_current_A = float(supply_current_A)
        eff = fx.check_effects(effects)
        consts = constants_from_params(params or default_params())
        self.consts = np.ascontiguousarray(fx.apply_to_constants(
            consts, {k: v for k, v in eff.items() if fx.EFFECTS[k].kind == "plant"}))
        self.mount = np.ascontiguousarray(fx.imu_mount(eff))
        self.delay_us = int(round(fx.delay_s(eff) * 1e6))  # relay edges act this late
        self.gyro_drift_dps_per_s = fx.gyro_drift(eff)  # added to gyro x and y, from the start
        self.t_start_us: int | None = None
        self.effects = eff
        self.x = initial_state(self.consts, 1)
        self.sensors = sensors
        self.rng = np.random.default_rng(seed)
        s = sensors or SensorParams(0.0, 0.0, 0.0, 0.0, 0.0)
        self.accel_bias = self.rng.normal(0.0, s.accel_bias_g, 3)
        self.gyro_bias = self.rng.normal(0.0, s.gyro_bias_dps, 3)
        self.thermistors = int(thermistors)
        self.period_s = float(period_s)
        self.t_us: int | None = None  # the plant's time: up to AHEAD_US past the emulator's
        self._now_us = 0  # the emulator's time at the last update
        self._snaps: list[tuple] = []  # the state at each boundary from the emulator's time on
        self.rewinds = 0  # times a relay edge learnt late sent the plant back
        self.log: list[tuple[float, float, float, tuple[bool, bool, bool]]] = []  # (t_s, theta, phi, relays)
        self.error: BaseException | None = None
        self._pins = (False, False, False)
        self._event_i = 0
        self._q_prev = self.x[0, L.S_Q:L.S_Q + 3].copy()
        self._left = np.full(1, np.inf)
        self._out = np.empty((1, L.N_OUT))
        self._scratch = (np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3),
                         np.empty(6))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.lock = threading.Lock()
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels now, on scratch copies: compiling
        holds the GIL for seconds, and in the running loop that would stall the harness's
        reader thread, then the harness, then the host's writes to the pty."""
        x = self.x.copy()
        step_inplace(self.consts, x, np.zeros((1, 3)), PLANT_DT_S, 1, self._left.copy(),
                     np.empty_like(self._out))
        tip, dtip, rot, v, w, r = (a.copy() for a in self._scratch)
        q = x[0, L.S_Q:L.S_Q + 3].copy()
        imu_reading(q, q, PLANT_DT_S, self.mount, tip, dtip, rot, v, w, r)

    # -- one update ---------------------------------------------------------------------------
    def update(self) -> None:
        """Run the plant ``AHEAD_US`` past the emulator's present time, the relays as they are,
        and queue the IMU samples the firmware will read (``IMU_AT``). A relay edge the plant
        learns of only after computing past it rewinds it to the edge: every sample from there
        on is computed again and replaces the queued ones."""
        now = self.h.sim_time_us()
        self._now_us = now
        if self.t_us is None:
            self.t_us = self.t_start_us = now
            self._snaps = [self._snapshot()]
            self.h.set_imu(*self._imu_raw())
            self._publish_thermistors()
            return
        events = self.h.relay_events
        if self._event_i < len(events):
            self._rewind(events[self._event_i].t_us + self.delay_us)
        cur = np.zeros((1, 3))
        samples = []
        while self.t_us < now + AHEAD_US:
            # relay state at the start of the sub-step (10 ms resolution of switching)
            while (self._event_i < len(events)
                   and events[self._event_i].t_us + self.delay_us <= self.t_us):
                ev = events[self._event_i]
                pins = list(self._pins)
                pins[ev.muscle] = ev.on
                self._pins = tuple(pins)  # type: ignore[assignment]
                self._event_i += 1
            cur[0] = [self.supply_current_A if p else 0.0 for p in self._pins]
            self._q_prev = self.x[0, L.S_Q:L.S_Q + 3].copy()
            with self.lock:
                step_inplace(self.consts, self.x, cur, PLANT_DT_S, 1, self._left, self._out)
                self.t_us += PLANT_DT_US
                self.log.append((self.t_us * 1e-6, float(self._out[0, L.O_THETA]),
                                 float(self._out[0, L.O_PHI]), self._pins))
                self._snaps.append(self._snapshot())
            samples.append((self.t_us, *self._imu_raw()))
        for i in range(0, len(samples), IMU_AT_BATCH):
            self.h.imu_at(samples[i:i + IMU_AT_BATCH])
        with self.lock:  # an edge not yet known happens after now: a rewind never goes earlier
            keep = next(i for i in range(len(self._snaps) - 1, -1, -1) if self._snaps[i][0] <= now)
            del self._snaps[:keep]
        self._publish_thermistors()

    def _snapshot(self) -> tuple:
        """The state at the sub-step boundary ``t_us``, before the relay edges due there."""
        return (self.t_us, self.x.copy(), self._q_prev.copy(), self._pins, self._event_i,
                self._left.copy(), len(self.log))

    def _rewind(self, t_act_us: int) -> None:
        """Back to the last boundary at or before ``t_act_us`` if the plant has run past it."""
        if t_act_us >= self.t_us:
            return
        with self.lock:
            i = max((k for k, sn in enumerate(self._snaps) if sn[0] <= t_act_us), default=0)
            t, x, q_prev, pins, event_i, left, n_log = self._snaps[i]
            self.t_us, self._pins, self._event_i = t, pins, event_i
            self.x[:], self._q_prev[:], self._left[:] = x, q_prev, left
            del self.log[n_log:]
            del self._snaps[i + 1:]
            self.rewinds += 1

    def _imu_raw(self) -> tuple[int, ...]:
        """The IMU registers (ax ay az gx gy gz, raw) for the plant's state at ``t_us``."""
        tip, dtip, rot, v, w, r = self._scratch
        q = self.x[0, L.S_Q:L.S_Q + 3].copy()
        imu_reading(q, self._q_prev, PLANT_DT_S, self.mount, tip, dtip, rot, v, w, r)
        a = r[:3] + self.accel_bias
        g = r[3:] + self.gyro_bias
        if self.gyro_drift_dps_per_s:
            drift = self.gyro_drift_dps_per_s * (self.t_us - self.t_start_us) * 1e-6
            g[:2] += drift  # g is this sample's own array (the sum above)
        if self.sensors is not None:
            a = a + self.rng.normal(0.0, self.sensors.accel_noise_g, 3)
            g = g + self.rng.normal(0.0, self.sensors.gyro_noise_dps, 3)
        return (*(_int16(x * P.ACCEL_LSB_PER_G) for x in a),
                *(_int16(x * P.GYRO_LSB_PER_DPS) for x in g))

    def _publish_thermistors(self) -> None:
        if not self.thermistors:
            return
        T = self.temperatures_C
        for k in range(3):
            if self.thermistors >> k & 1:
                self.h.set_adc(k, int(round(P.celsius_to_ntc_adc(float(T[k])))))

    @property
    def theta_deg(self) -> float:
        """The head's tilt at the emulator's present time (the plant runs ahead of it)."""
        with self.lock:
            past = [e for e in self.log[-(AHEAD_US // PLANT_DT_US + 2):] if e[0] * 1e6 <= self._now_us]
            return past[-1][1] if past else 0.0

    @property
    def temperatures_C(self) -> np.ndarray:
        """The springs' temperatures at the emulator's present time."""
        with self.lock:
            if not self._snaps:
                return self.x[0, L.S_T:L.S_T + 3].copy()
            sn = max((sn for sn in self._snaps if sn[0] <= self._now_us), key=lambda sn: sn[0],
                     default=self._snaps[0])
            return sn[1][0, L.S_T:L.S_T + 3].copy()

    # -- background thread --------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.wait(self.period_s):
                self.update()
        except HarnessError as exc:
            if not self._stop.is_set():
                self.error = exc
        except BaseException as exc:  # noqa: BLE001 - reported to the test through .error
            self.error = exc

    def start(self) -> "SimulatedNeck":
        self.update()
        self._thread = threading.Thread(target=self._run, name="sim-neck", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)


class EmulatedRig:
    """The firmware in simavr with a :class:`SimulatedNeck`: a rig on a pseudo-terminal.

    ``port`` is the path to pass as ``--port`` to every ``rig`` command. The bench supply's
    current is the number in :attr:`supply_file` (write another, e.g. ``echo 6.5 > FILE``, and
    it applies within 0.2 s). Builds the firmware first (``make -C firmware``; raises
    ``HarnessUnavailable`` naming what to install when the AVR toolchain or simavr is missing).
    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, supply_current_A: float = 7.0, params: NeckParams | None = None,
                 effects: Mapping[str, Mapping[str, float]] | None = None, thermistors: int = 0,
                 seed: int = 0, supply_file: str | os.PathLike[str] | None = None) -> None:
        if not 0 < supply_current_A <= 8.0:
            raise ValueError(f"supply current must lie in (0, 8] A, got {supply_current_A}")
        if supply_file is None:
            self._tmp = tempfile.mkdtemp(prefix="neck-emulator-")
            supply_file = Path(self._tmp) / "supply_A"
        self.supply_file = Path(supply_file)
        self.supply_file.write_text(f"{supply_current_A:g}\n")
        self._mtime = self.supply_file.stat().st_mtime_ns
        elf, hil = build()
        self.harness = SimavrHarness(elf, hil, speed=1.0)
        try:
            self.neck = SimulatedNeck(self.harness, supply_current_A=supply_current_A,
                                      params=params, effects=effects, thermistors=thermistors,
                                      seed=seed).start()
            self.harness.run()
        except BaseException:
            self.harness.close()
            raise
        self.port: str = self.harness.pty_path
        self.supply_error: str | None = None
        self._stop = threading.Event()
        self._watch = threading.Thread(target=self._watch_supply, name="emulated-supply",
                                       daemon=True)
        self._watch.start()

    def _watch_supply(self) -> None:
        while not self._stop.wait(0.1):
            try:
                m = self.supply_file.stat().st_mtime_ns
                if m == self._mtime:
                    continue
                text = self.supply_file.read_text().strip()
                if not text:  # a writer's truncation before its write: read again next time
                    continue
                self._mtime = m
                amps = float(text)
                if not 0 < amps <= 8.0:
                    raise ValueError(f"{amps} A outside (0, 8]")
                self.neck.supply_current_A = amps
                self.supply_error = None
            except (OSError, ValueError) as exc:
                self.supply_error = f"{self.supply_file}: {exc}"

    @property
    def supply_current_A(self) -> float:
        return self.neck.supply_current_A

    def check(self) -> None:
        """Raise if the emulator or the simulated neck has failed."""
        if self.neck.error is not None:
            raise HarnessError(f"simulated neck failed: {self.neck.error!r}")
        if self.harness._proc.poll() is not None:
            raise HarnessError(f"emulator exited; stderr: {self.harness.stderr_tail()}")

    def close(self) -> None:
        self._stop.set()
        self.neck.stop()
        self.harness.close()

    def __enter__(self) -> "EmulatedRig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
