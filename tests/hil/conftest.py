"""Fixtures for the hardware-in-the-loop tests: the real firmware ELF in simavr,
talked to over the harness's pty with pyserial, exactly as a host talks to a
real UNO. Skips (with the reason) only when the AVR toolchain or simavr is not
installed; CI installs them, so there the tests run.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterator

import pytest

serial = pytest.importorskip("serial", reason="pyserial is needed to talk to the emulated UNO")

from neck_env.rig import protocol as P  # noqa: E402
from neck_env.rig.simavr import SimavrHarness, build, toolchain_missing  # noqa: E402

REPLY_TYPES = (P.MsgType.ACK, P.MsgType.NAK, P.MsgType.HELLO_REPLY, P.MsgType.STATUS)


@dataclass(frozen=True)
class Rx:
    """One received frame: decoded message, raw frame, host arrival time."""

    msg: object
    frame: P.Frame
    t_wall: float


class FirmwareLink:
    """Minimal host side of the protocol for tests: a reader thread decodes
    everything the firmware sends into one list; requests are matched to their
    replies by header SEQ; an optional heartbeat thread keeps the link alive.

    ``via_harness=True`` sends host frames through the harness's UART injection
    instead of the pty (for unpaced runs, where they must not interleave with
    injected heartbeats); replies always come back over the pty.
    """

    def __init__(self, harness: SimavrHarness, ser: "serial.Serial") -> None:
        self.h = harness
        self.ser = ser
        self.decoder = P.FrameDecoder()
        self.rx: list[Rx] = []
        self.decode_errors: list[str] = []
        self.via_harness = False
        self._cv = threading.Condition()
        self._wlock = threading.Lock()
        self._seq = 0
        self._stop = threading.Event()
        self._hb_stop: threading.Event | None = None
        self._hb_thread: threading.Thread | None = None
        self._reader = threading.Thread(target=self._read_loop, name="fw-link-reader", daemon=True)
        self._reader.start()

    # -- receiving -----------------------------------------------------------
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.ser.read(max(1, self.ser.in_waiting))
            except (serial.SerialException, OSError, TypeError):
                if self._stop.is_set():
                    return
                time.sleep(0.01)
                continue
            if not data:
                continue
            now = time.monotonic()
            frames = self.decoder.feed(data)
            if not frames:
                continue
            with self._cv:
                for fr in frames:
                    try:
                        msg = P.decode_message(fr)
                    except P.ProtocolError as e:
                        self.decode_errors.append(str(e))
                        continue
                    self.rx.append(Rx(msg, fr, now))
                self._cv.notify_all()

    def mark(self) -> int:
        """Index into :attr:`rx` to wait for later messages from."""
        with self._cv:
            return len(self.rx)

    def wait_for(self, pred: Callable[[Rx], bool], timeout: float = 2.0, start: int = 0) -> Rx | None:
        deadline = time.monotonic() + timeout
        with self._cv:
            i = start
            while True:
                while i < len(self.rx):
                    if pred(self.rx[i]):
                        return self.rx[i]
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cv.wait(left)

    def messages(self, kind: type, start: int = 0) -> list:
        """Received messages of exactly this class (Status is not Telemetry here)."""
        with self._cv:
            return [r.msg for r in self.rx[start:] if type(r.msg) is kind]

    # -- sending -------------------------------------------------------------
    def next_seq(self) -> int:
        with self._wlock:
            self._seq = (self._seq + 1) & 0xFF
            return self._seq

    def send_raw(self, data: bytes) -> None:
        if self.via_harness:
            self.h.send_uart(data)
            return
        with self._wlock:
            self.ser.write(data)
            self.ser.flush()

    def send(self, msg) -> int:
        seq = self.next_seq()
        self.send_raw(P.encode(msg, seq))
        return seq

    def request(self, msg, timeout: float = 1.0):
        """Send and return the reply (ACK/NAK/HELLO_REPLY/STATUS with our SEQ)."""
        start = self.mark()
        seq = self.send(msg)
        r = self.wait_for(lambda r: r.frame.type in REPLY_TYPES and r.frame.seq == seq, timeout, start)
        assert r is not None, f"no reply to {msg!r} (seq {seq}) within {timeout} s"
        return r.msg

    def status(self, timeout: float = 1.0) -> P.Status:
        t = self.request(P.GetStatus(), timeout)
        assert isinstance(t, P.Status), t
        return t

    def expect_ack(self, msg, timeout: float = 1.0) -> P.Ack:
        r = self.request(msg, timeout)
        assert isinstance(r, P.Ack), f"{msg!r} -> {r!r}"
        return r

    # -- heartbeat -----------------------------------------------------------
    def start_heartbeat(self, period_s: float = 0.05) -> None:
        self.stop_heartbeat()
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(period_s):
                try:
                    self.send(P.Heartbeat())
                except (serial.SerialException, OSError):
                    return

        self._hb_stop = stop
        self._hb_thread = threading.Thread(target=beat, name="fw-heartbeat", daemon=True)
        self._hb_thread.start()

    def stop_heartbeat(self) -> None:
        if self._hb_stop is not None:
            self._hb_stop.set()
            assert self._hb_thread is not None
            self._hb_thread.join(2.0)
        self._hb_stop = self._hb_thread = None

    def close(self) -> None:
        self.stop_heartbeat()
        self._stop.set()
        self._reader.join(2.0)
        try:
            self.ser.close()
        except Exception:
            pass


@pytest.fixture(scope="session")
def fw_binaries() -> tuple:
    reason = toolchain_missing()
    if reason:
        pytest.skip(f"HIL toolchain not installed: {reason}")
    return build()


@pytest.fixture
def start_rig(fw_binaries) -> Iterator[Callable[..., FirmwareLink]]:
    """Factory: ``start_rig(speed=1.0, imu_absent=False)`` -> a :class:`FirmwareLink`
    to a freshly booted firmware (its BOOT frame already received)."""
    elf, hil = fw_binaries
    opened: list[tuple[SimavrHarness, FirmwareLink]] = []

    def start(speed: float = 1.0, imu_absent: bool = False) -> FirmwareLink:
        h = SimavrHarness(elf, hil, speed=speed, imu_absent=imu_absent)
        try:
            # Open the pty before the MCU runs: pyserial flushes input on open.
            ser = serial.Serial(h.pty_path, 115200, timeout=0.02)
            link = FirmwareLink(h, ser)
        except Exception:
            h.close()
            raise
        opened.append((h, link))
        h.run()
        boot = link.wait_for(lambda r: isinstance(r.msg, P.Boot), timeout=3.0)
        assert boot is not None, f"no BOOT frame; harness stderr: {h.stderr_tail()}"
        return link

    yield start
    for h, link in opened:
        link.close()
        h.close()


@pytest.fixture
def closed_loop(fw_binaries) -> Iterator[Callable[..., tuple]]:
    """Factory: ``closed_loop(supply_A=7.0, imu_absent=False, seed=0, neck=True)`` -> (paced
    harness running the firmware, the simulator playing the neck or None). Everything started
    is stopped at teardown, the neck before its harness."""
    from neck_env.rig.sim_neck import SimulatedNeck

    elf, hil = fw_binaries
    made: list = []

    def start(supply_A: float = 7.0, imu_absent: bool = False, seed: int = 0,
              neck: bool = True) -> tuple:
        h = SimavrHarness(elf, hil, speed=1.0, imu_absent=imu_absent)
        made.append(h.close)
        sim = None
        if neck:
            sim = SimulatedNeck(h, supply_current_A=supply_A, seed=seed).start()
            made.append(sim.stop)
        h.run()
        return h, sim

    yield start
    for stop in reversed(made):
        stop()


@pytest.fixture
def one_target():
    """One non-upright waypoint after the 2 s upright start, held for a whole short episode."""
    from neck_env.targets import TargetSpec

    return TargetSpec(upright_probability=0.0, step_probability=1.0, hold_s=(20.0, 20.0),
                      ramp_s=(2.0, 2.0), theta_min_deg=12.0)


@pytest.fixture
def rig(closed_loop):
    """Factory: ``rig(supply_A=7.0, imu_absent=False, seed=0)`` -> (harness, simulated neck,
    ``RigLink`` the host code talks through); links closed at teardown, before the rigs."""
    from neck_env.rig.link import RigLink

    links = []

    def start(supply_A: float = 7.0, imu_absent: bool = False, seed: int = 0):
        h, neck = closed_loop(supply_A, imu_absent=imu_absent, seed=seed)
        link = RigLink(h.pty_path, open_timeout=5.0)
        links.append(link)
        return h, neck, link

    yield start
    for link in links:
        link.close()
