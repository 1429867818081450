"""Run the real firmware under simavr: the hardware-in-the-loop harness.

:class:`SimavrHarness` builds the firmware and the C harness (``make -C
firmware all hil``; make only rebuilds what changed), starts
``firmware/build/neck_hil`` on the firmware ELF, and exposes

* the pseudo-terminal that stands in for the UNO's serial port -- open it with
  ``serial.Serial(h.pty_path, 115200)`` *before* :meth:`SimavrHarness.run`,
  because pyserial discards pending input when it opens a port;
* relay pin changes (:attr:`SimavrHarness.relay_events`, :meth:`wait_relay`),
  time-stamped in simulated microseconds;
* the fake world: :meth:`set_imu`, :meth:`set_imu_absent`, :meth:`set_adc`, ...

The control channel is the harness's stdin/stdout, line-based text, documented
in ``firmware/hil/README.md``. Every command gets exactly one reply line; the
asynchronous ``RELAY``/``RESET``/``CRASH`` event lines are sorted out by a reader
thread.
"""

from __future__ import annotations

import collections
import os
import queue
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

__all__ = [
    "HarnessUnavailable",
    "HarnessError",
    "RelayEvent",
    "SimavrHarness",
    "firmware_dir",
    "toolchain_missing",
    "build",
]

_ARDUINO_CORE = Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h")
_SIMAVR_HEADER = Path("/usr/include/simavr/sim_avr.h")


class HarnessUnavailable(RuntimeError):
    """The toolchain, simavr or the harness binary is missing (nothing to run)."""


class HarnessError(RuntimeError):
    """The harness misbehaved: refused a command, died, or did not answer."""


@dataclass(frozen=True)
class RelayEvent:
    """A relay pin changed: at simulated time ``t_us``, muscle ``muscle`` went ``on``."""

    t_us: int
    muscle: int
    on: bool


def firmware_dir() -> Path:
    """The ``firmware/`` directory: ``$NECK_FIRMWARE_DIR`` or the source checkout's."""
    env = os.environ.get("NECK_FIRMWARE_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "firmware"


def toolchain_missing(fw_dir: Path | None = None) -> str | None:
    """Why the HIL harness cannot be built here, or ``None`` if it can.

    Checked up front so callers (tests) can skip with a precise reason instead
    of failing inside make.
    """
    fw = fw_dir or firmware_dir()
    if not (fw / "Makefile").is_file():
        return f"firmware sources not found at {fw} (set NECK_FIRMWARE_DIR)"
    needs = {
        "make": "make",
        "avr-gcc": "gcc-avr",
        "avr-g++": "gcc-avr",
        "avr-objcopy": "binutils-avr",
        "cc": "a host C compiler (gcc)",
    }
    for exe, pkg in needs.items():
        if shutil.which(exe) is None:
            return f"{exe} not found (install {pkg})"
    if not _ARDUINO_CORE.is_file():
        return f"Arduino AVR core not found at {_ARDUINO_CORE.parent} (install arduino-core-avr)"
    if not _SIMAVR_HEADER.is_file():
        return f"simavr headers not found at {_SIMAVR_HEADER} (install libsimavr-dev simavr)"
    return None


def build(fw_dir: Path | None = None, timeout: float = 300.0) -> tuple[Path, Path]:
    """``make -C firmware all hil``; returns ``(firmware_elf, harness_binary)``.

    Raises :class:`HarnessUnavailable` when the toolchain is missing and
    :class:`HarnessError` when the build itself fails.
    """
    fw = fw_dir or firmware_dir()
    reason = toolchain_missing(fw)
    if reason:
        raise HarnessUnavailable(reason)
    proc = subprocess.run(
        ["make", "-C", str(fw), "all", "hil"],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if proc.returncode != 0:
        raise HarnessError(f"firmware/harness build failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    elf, hil = fw / "build" / "neck_fw.elf", fw / "build" / "neck_hil"
    for p in (elf, hil):
        if not p.is_file():
            raise HarnessUnavailable(f"build finished but {p} is missing")
    return elf, hil


class SimavrHarness:
    """One simulated UNO running the firmware, plus its fake IMU, ADC and relays.

    Typical use::

        with SimavrHarness() as h:
            ser = serial.Serial(h.pty_path, 115200, timeout=0.1)
            h.run()
            ...

    ``speed`` is simulated time per wall time (1.0 = real time, the default,
    which keeps the firmware's millis()-based timeouts meaningful for a host
    that acts on wall-clock time; 0 = as fast as the emulator goes, about 5x).
    """

    def __init__(
        self,
        elf: str | os.PathLike[str] | None = None,
        harness: str | os.PathLike[str] | None = None,
        *,
        speed: float = 1.0,
        imu_absent: bool = False,
        build_first: bool = True,
        fw_dir: Path | None = None,
        verbose: bool = False,
        start_timeout: float = 10.0,
    ) -> None:
        if elf is None or harness is None:
            if build_first:
                b_elf, b_hil = build(fw_dir)
            else:
                fw = fw_dir or firmware_dir()
                b_elf, b_hil = fw / "build" / "neck_fw.elf", fw / "build" / "neck_hil"
            elf = elf or b_elf
            harness = harness or b_hil
        self.elf = Path(elf)
        self.harness = Path(harness)
        for p, what in ((self.elf, "firmware ELF"), (self.harness, "harness binary")):
            if not p.is_file():
                raise HarnessUnavailable(f"{what} not found: {p} (run make -C firmware all hil)")

        argv = [str(self.harness), "--speed", repr(float(speed))]
        if imu_absent:
            argv.append("--imu-absent")
        if verbose:
            argv.append("-v")
        argv.append(str(self.elf))

        self._lock = threading.Lock()  # one command/reply exchange at a time
        self._replies: queue.Queue[str] = queue.Queue()
        self._events_cv = threading.Condition()
        self._relay_events: list[RelayEvent] = []
        self._resets: list[int] = []
        self._crash: str | None = None
        self._stderr_tail: collections.deque[str] = collections.deque(maxlen=50)
        self._closed = False
        self.running = False

        self._proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self._stderr_thread = threading.Thread(target=self._drain_stderr, name="neck_hil-stderr", daemon=True)
        self._stderr_thread.start()
        first = self._readline_with_timeout(start_timeout)
        if not first or not first.startswith("PTY "):
            self.close()
            raise HarnessError(f"harness did not announce its pty (got {first!r}); stderr: {self.stderr_tail()}")
        self.pty_path: str = first.split(None, 1)[1].strip()
        self._reader = threading.Thread(target=self._read_stdout, name="neck_hil-stdout", daemon=True)
        self._reader.start()

    # ------------------------------------------------------------------ plumbing

    def _readline_with_timeout(self, timeout: float) -> str | None:
        box: list[str] = []
        t = threading.Thread(target=lambda: box.append(self._proc.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        t.start()
        t.join(timeout)
        return box[0] if box else None

    def _drain_stderr(self) -> None:
        assert self._proc.stderr is not None
        for line in self._proc.stderr:
            self._stderr_tail.append(line.rstrip("\n"))

    def _read_stdout(self) -> None:
        assert self._proc.stdout is not None
        for raw in self._proc.stdout:
            line = raw.strip()
            if not line:
                continue
            kind = line.split(None, 1)[0]
            if kind == "RELAY":
                _, t, k, v = line.split()
                with self._events_cv:
                    self._relay_events.append(RelayEvent(int(t), int(k), v == "1"))
                    self._events_cv.notify_all()
            elif kind == "RESET":
                with self._events_cv:
                    self._resets.append(int(line.split()[1]))
                    self._events_cv.notify_all()
            elif kind == "CRASH":
                with self._events_cv:
                    self._crash = line
                    self._events_cv.notify_all()
            else:
                self._replies.put(line)
        # EOF: wake anyone waiting for a reply or an event.
        self._replies.put("")
        with self._events_cv:
            self._events_cv.notify_all()

    def stderr_tail(self) -> str:
        """The harness's last stderr lines (simavr warnings), for error messages."""
        return "\n".join(self._stderr_tail)

    def command(self, line: str, timeout: float = 5.0) -> str:
        """Send one control line and return its reply line (raises on ``ERR``)."""
        if self._closed or self._proc.poll() is not None:
            raise HarnessError(f"harness is not running; stderr: {self.stderr_tail()}")
        with self._lock:
            assert self._proc.stdin is not None
            try:
                self._proc.stdin.write(line + "\n")
                self._proc.stdin.flush()
            except (BrokenPipeError, OSError) as e:
                raise HarnessError(f"harness control channel closed: {e}") from e
            try:
                reply = self._replies.get(timeout=timeout)
            except queue.Empty:
                raise HarnessError(f"no reply to {line!r} within {timeout} s") from None
        if reply == "":
            raise HarnessError(f"harness exited while handling {line!r}; stderr: {self.stderr_tail()}")
        if reply.startswith("ERR"):
            raise HarnessError(f"harness refused {line!r}: {reply}")
        return reply

    # ------------------------------------------------------------------ control

    def run(self) -> None:
        """Release the MCU from reset (open the pty first)."""
        self.command("RUN")
        self.running = True

    def sim_time_us(self) -> int:
        """Current simulated time in microseconds."""
        return int(self.command("TIME?").split()[1])

    def relay_pins(self) -> tuple[bool, bool, bool]:
        """Relay pin states right now (PORTD bits 5..7)."""
        parts = self.command("RELAYS?").split()
        return (parts[2] == "1", parts[3] == "1", parts[4] == "1")

    def set_imu(self, ax: int, ay: int, az: int, gx: int, gy: int, gz: int) -> None:
        """Raw int16 register values the fake MPU6050 returns from now on."""
        self.command(f"IMU {int(ax)} {int(ay)} {int(az)} {int(gx)} {int(gy)} {int(gz)}")

    def imu_at(self, samples: Sequence[Sequence[int]]) -> None:
        """Queue IMU samples ``(t_us, ax, ay, az, gx, gy, gz)`` (raw, ``t_us`` ascending): each
        is served from its simulated time on, replacing queued samples at or after the first."""
        self.command("IMU_AT " + " ".join(" ".join(str(int(v)) for v in smp) for smp in samples))

    def set_imu_temp(self, raw: int) -> None:
        self.command(f"IMU_TEMP {int(raw)}")

    def set_imu_absent(self, absent: bool = True) -> None:
        """Make the MPU6050 stop ACKing its address (unplugged), or come back
        (powered up again: asleep, default registers)."""
        self.command(f"IMU_ABSENT {1 if absent else 0}")

    def set_imu_whoami(self, value: int) -> None:
        """Fake a different chip (e.g. 0x70 for an MPU6500 clone)."""
        self.command(f"IMU_WHOAMI {int(value)}")

    def imu_register(self, reg: int) -> int:
        """Read the fake MPU6050's register as the firmware would."""
        return int(self.command(f"IMUREG? {int(reg)}").split()[2])

    def set_adc(self, channel: int, value: int) -> None:
        """Raw ADC count (0..1023) the firmware reads on A<channel>."""
        self.command(f"ADC {int(channel)} {int(value)}")

    def set_speed(self, speed: float) -> None:
        """Simulated/real time ratio (0 = unpaced)."""
        self.command(f"SPEED {float(speed)!r}")

    def send_uart(self, data: bytes) -> None:
        """Inject bytes into the MCU's UART directly (kept whole, never interleaved
        with other injected frames). Useful in unpaced runs."""
        if data:
            self.command("SEND " + data.hex())

    def inject_every(self, period_ms: int, data: bytes = b"", slot: int = 0) -> None:
        """Inject ``data`` into the UART every ``period_ms`` of *simulated* time,
        first one period from now (``period_ms`` 0 stops the slot). Four slots
        (0..3), e.g. heartbeats on one and a command pattern on another: this
        keeps pace with an unpaced MCU where a wall-clock host thread cannot."""
        if period_ms <= 0:
            self.command(f"INJECT {int(slot)} 0")
        else:
            self.command(f"INJECT {int(slot)} {int(period_ms)} {data.hex()}")

    def reset(self) -> None:
        """External reset (the RESET pin)."""
        self.command("RESET")

    def stats(self) -> dict[str, int]:
        parts = self.command("STATS?").split()[1:]
        return {k: int(v) for k, v in (p.split("=", 1) for p in parts)}

    # ------------------------------------------------------------------ events

    @property
    def relay_events(self) -> list[RelayEvent]:
        with self._events_cv:
            return list(self._relay_events)

    @property
    def resets(self) -> list[int]:
        """Simulated times (us) of MCU resets seen (watchdog or software)."""
        with self._events_cv:
            return list(self._resets)

    @property
    def crash(self) -> str | None:
        return self._crash

    def wait_relay(
        self, muscle: int, on: bool, timeout: float = 5.0, start: int = 0
    ) -> RelayEvent | None:
        """First event for ``muscle`` switching to ``on`` at index >= ``start`` of
        :attr:`relay_events`, waiting up to ``timeout`` wall seconds."""
        deadline = time.monotonic() + timeout
        with self._events_cv:
            while True:
                for ev in self._relay_events[start:]:
                    if ev.muscle == muscle and ev.on == on:
                        return ev
                left = deadline - time.monotonic()
                if left <= 0 or self._proc.poll() is not None:
                    return None
                self._events_cv.wait(left)

    def wait_reset(self, timeout: float = 5.0, start: int = 0) -> int | None:
        deadline = time.monotonic() + timeout
        with self._events_cv:
            while len(self._resets) <= start:
                left = deadline - time.monotonic()
                if left <= 0 or self._proc.poll() is not None:
                    return None
                self._events_cv.wait(left)
            return self._resets[start]

    # ------------------------------------------------------------------ lifetime

    def close(self, timeout: float = 3.0) -> None:
        """Stop the harness (QUIT, then terminate/kill if it does not listen)."""
        if self._closed:
            return
        self._closed = True
        proc = self._proc
        if proc.poll() is None:
            try:
                assert proc.stdin is not None
                proc.stdin.write("QUIT\n")
                proc.stdin.flush()
                proc.stdin.close()  # EOF also makes it exit
            except (BrokenPipeError, OSError, ValueError):
                pass
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        # The process is gone, so the reader threads hit EOF; join them before
        # closing the pipes under their feet.
        for t in (getattr(self, "_reader", None), self._stderr_thread):
            if t is not None:
                t.join(timeout)
        for stream in (proc.stdout, proc.stderr):
            try:
                if stream is not None:
                    stream.close()
            except OSError:
                pass

    def __enter__(self) -> "SimavrHarness":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # last resort: never leave an emulator spinning
        try:
            if not self._closed and self._proc.poll() is None:
                self._proc.kill()
        except Exception:
            pass

