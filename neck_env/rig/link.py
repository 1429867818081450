"""The serial link to the neck firmware: frames in and out over pyserial, replies matched to
requests, telemetry delivered as it arrives.

:class:`RigLink` opens a real port (``/dev/ttyACM0``, ``COM3``) or any pyserial URL
(``serial_for_url``: ``loop://``, ``socket://host:port``, ``rfc2217://...``). A reader thread
decodes everything the firmware sends (``protocol.FrameDecoder`` resynchronises after noise);
requests wait for the reply carrying their sequence number, with a timeout and retries for
commands that are safe to repeat. Telemetry frames go to a bounded queue and to an optional
callback.

Safety on the host side of the link (the firmware has its own, see ``firmware/PROTOCOL.md``):

* :meth:`RigLink.all_off` sends ``SET_RELAYS 0`` and ``STOP`` best effort, never raises, and is
  called on every error path and on :meth:`close`;
* the heartbeat is a **lease**: :meth:`start_heartbeat` starts a thread that sends
  ``HEARTBEAT`` every ``period_s`` only while the lease that the caller renews with
  :meth:`renew` (the hardware env does at every step) has not expired. It bridges a slow
  policy evaluation or a garbage-collector pause, but a host whose main loop hangs or dies
  stops renewing it, so the firmware's 250 ms watchdog still switches the relays off
  (lease + 250 ms after the last renewal). A plain background heartbeat would keep the
  relays of a hung host on forever.

A port that vanishes (USB unplugged, emulator gone) raises :class:`RigLinkLost` at the next
use; :meth:`reconnect` reopens the same port and checks the firmware again.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from typing import Callable

from . import protocol as P
from .errors import RigError, RigLinkLost, RigRefused, RigTimeout

try:  # pyserial is a dependency; imported lazily-friendly so the message is clear if absent
    import serial
except ImportError as exc:  # pragma: no cover - pyserial is in the install requirements
    raise ImportError("neck_env.rig needs pyserial: pip install pyserial") from exc

__all__ = ["RigError", "RigLinkLost", "RigTimeout", "RigRefused", "RigLink", "Received"]

BAUD = 115200
STALE_PARTIAL_S = 0.1  # the firmware's rule for a partial frame that stopped arriving
REPLY_TYPES = (P.MsgType.ACK, P.MsgType.NAK, P.MsgType.HELLO_REPLY, P.MsgType.STATUS)


@dataclass(frozen=True)
class Received:
    """A decoded message from the firmware and its host arrival time (``time.monotonic``)."""

    msg: object
    seq: int
    t_host: float


class RigLink:
    """Host end of the firmware protocol on one serial port or URL.

    ``port``: a device path or a pyserial URL. ``open_timeout``: how long to wait for the
    firmware to answer ``HELLO`` (an UNO resets when its port opens and boots in ~1.6 s behind
    its bootloader). Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, port: str, baud: int = BAUD, open_timeout: float = 4.0,
                 reply_timeout: float = 0.5, on_telemetry: Callable[[P.Telemetry, float], None] | None = None,
                 _serial: "serial.SerialBase | None" = None) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a device path or pyserial URL, got {port!r}")
        self.port = port
        self.baud = int(baud)
        self.reply_timeout = float(reply_timeout)
        self.on_telemetry = on_telemetry
        self.hello: P.HelloReply | None = None
        self.boots: list[P.Boot] = []
        self.nak_count = 0
        self.decode_errors = 0
        self._given_serial = _serial
        self._ser: serial.SerialBase | None = None
        self._decoder = P.FrameDecoder()
        self._cv = threading.Condition()
        self._wlock = threading.Lock()
        self._replies: collections.deque[Received] = collections.deque(maxlen=64)
        self.telemetry: collections.deque[Received] = collections.deque(maxlen=4096)
        self._seq = 0
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        self._lost: BaseException | None = None
        self._lease_until = 0.0
        self._hb_stop: threading.Event | None = None
        self._hb_thread: threading.Thread | None = None
        self._open(open_timeout)

    # -- opening ------------------------------------------------------------------------------
    def _open(self, open_timeout: float) -> None:
        try:
            if self._given_serial is not None:
                self._ser = self._given_serial
            else:
                self._ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.02,
                                                  write_timeout=0.5)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise RigLinkLost(f"cannot open {self.port}: {exc}") from exc
        self._stop.clear()
        self._lost = None
        self._decoder.reset()
        self._reader = threading.Thread(target=self._read_loop, name=f"rig-reader {self.port}",
                                        daemon=True)
        self._reader.start()
        deadline = time.monotonic() + open_timeout
        last: Exception | None = None
        while time.monotonic() < deadline:
            try:
                reply = self.request(P.Hello(), timeout=min(0.5, max(0.05, deadline - time.monotonic())))
            except RigTimeout as exc:
                last = exc
                continue
            except RigError:
                self.close(all_off=False)
                raise
            if not isinstance(reply, P.HelloReply):
                raise RigRefused(f"{self.port}: HELLO answered with {reply!r}")
            if reply.protocol_version != P.PROTOCOL_VERSION:
                self.close()
                raise RigRefused(f"{self.port}: firmware speaks protocol {reply.protocol_version}, "
                                 f"this host {P.PROTOCOL_VERSION}: flash the firmware of this "
                                 f"checkout (firmware/README.md)")
            self.hello = reply
            return
        self.close()
        raise RigTimeout(f"{self.port}: no answer to HELLO within {open_timeout:.1f} s "
                         f"(is the neck firmware flashed, and the baud rate {self.baud}?)"
                         + (f"; last error: {last}" if last else ""))

    def reconnect(self, open_timeout: float = 4.0) -> None:
        """Close and reopen the same port (after a USB glitch); checks HELLO again."""
        self.close(all_off=False)
        self._given_serial = None
        self._open(open_timeout)

    # -- receiving ----------------------------------------------------------------------------
    def _read_loop(self) -> None:
        ser = self._ser
        last_rx = time.monotonic()
        while not self._stop.is_set():
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._stop.is_set():
                    with self._cv:
                        self._lost = exc
                        self._cv.notify_all()
                return
            now = time.monotonic()
            if data:
                last_rx = now
                frames = self._decoder.feed(data)
            elif self._decoder.pending and now - last_rx > STALE_PARTIAL_S:
                # A truncated frame: give up on it as the firmware does (PROTOCOL.md), so a
                # genuine frame hidden behind its first bytes is still found.
                frames = self._decoder.flush_partial()
            else:
                continue
            for fr in frames:
                self._dispatch(fr, now)

    def _dispatch(self, fr: P.Frame, now: float) -> None:
        try:
            msg = P.decode_message(fr)
        except P.ProtocolError:
            self.decode_errors += 1
            return
        rx = Received(msg, fr.seq, now)
        if type(msg) is P.Telemetry:
            self.telemetry.append(rx)
            if self.on_telemetry is not None:
                self.on_telemetry(msg, now)
        elif isinstance(msg, P.Boot):
            self.boots.append(msg)
        with self._cv:
            if fr.type in REPLY_TYPES:
                self._replies.append(rx)
            self._cv.notify_all()

    @property
    def lost(self) -> BaseException | None:
        """Why the port failed since it was (re)opened (the reader's error), else None; a lost
        link needs ``reconnect()`` before it carries commands again."""
        return self._lost

    def check(self) -> None:
        """Raise :class:`RigLinkLost` if the port has failed since it was opened."""
        if self._lost is not None:
            raise RigLinkLost(f"{self.port}: serial link lost: {self._lost}")

    # -- sending ------------------------------------------------------------------------------
    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def send(self, msg: P.HostMessage) -> int:
        """Send one message; returns its sequence number. Raises :class:`RigLinkLost`."""
        self.check()
        with self._wlock:
            seq = self._next_seq()
            data = P.encode(msg, seq)
            try:
                assert self._ser is not None
                self._ser.write(data)
                self._ser.flush()
            except (serial.SerialException, OSError, AttributeError, AssertionError) as exc:
                self._lost = exc
                raise RigLinkLost(f"{self.port}: write failed: {exc}") from exc
        return seq

    def request(self, msg: P.HostMessage, timeout: float | None = None, retries: int = 0):
        """Send and return the reply with the same sequence number (ACK, NAK, HELLO_REPLY or
        STATUS). ``retries``: resend after a timeout (only for idempotent commands)."""
        timeout = self.reply_timeout if timeout is None else timeout
        for attempt in range(retries + 1):
            seq = self.send(msg)
            deadline = time.monotonic() + timeout
            with self._cv:
                while True:
                    for rx in self._replies:
                        if rx.seq == seq:
                            self._replies.remove(rx)
                            if isinstance(rx.msg, P.Nak):
                                self.nak_count += 1
                            return rx.msg
                    if self._lost is not None:
                        raise RigLinkLost(f"{self.port}: serial link lost: {self._lost}")
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cv.wait(left)
        raise RigTimeout(f"{self.port}: no reply to {type(msg).__name__} within {timeout:.2f} s"
                         f" ({retries + 1} attempt(s))")

    def command(self, msg: P.HostMessage, timeout: float | None = None, retries: int = 1) -> P.Ack:
        """Send a command that must be ACKed; NAK raises :class:`RigRefused`."""
        reply = self.request(msg, timeout, retries)
        if isinstance(reply, P.Nak):
            raise RigRefused(f"{self.port}: firmware rejected {type(msg).__name__}: "
                             f"{getattr(reply.error_code, 'name', reply.error_code)}")
        if not isinstance(reply, P.Ack):
            raise RigRefused(f"{self.port}: {type(msg).__name__} answered with {reply!r}")
        return reply

    def status(self, timeout: float | None = None) -> P.Status:
        reply = self.request(P.GetStatus(), timeout, retries=1)
        if not isinstance(reply, P.Status):
            raise RigRefused(f"{self.port}: GET_STATUS answered with {reply!r}")
        return reply

    def keepalive(self) -> None:
        """One heartbeat (for a caller that waits with the relays off)."""
        self.send(P.Heartbeat())

    def start_heartbeat(self, period_s: float = 0.1) -> None:
        """Start the lease heartbeat thread (see the module docstring); idempotent."""
        if not 0.01 <= period_s <= 0.2:
            raise ValueError(f"heartbeat period must lie in [0.01, 0.2] s (the firmware's "
                             f"watchdog is 250 ms), got {period_s}")
        if self._hb_thread is not None and self._hb_thread.is_alive():
            return
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(period_s):
                if time.monotonic() >= self._lease_until:
                    continue
                try:
                    self.send(P.Heartbeat())
                except RigError:
                    return  # the port is gone; whoever uses the link next gets the error

        self._hb_stop = stop
        self._hb_thread = threading.Thread(target=beat, name=f"rig-heartbeat {self.port}",
                                           daemon=True)
        self._hb_thread.start()

    def renew(self, lease_s: float) -> None:
        """Let the heartbeat thread feed the firmware for ``lease_s`` more seconds."""
        self._lease_until = time.monotonic() + float(lease_s)

    def expire(self) -> None:
        """End the lease now: from here on only explicit commands feed the firmware."""
        self._lease_until = 0.0

    def stop_heartbeat(self) -> None:
        self.expire()
        if self._hb_stop is not None:
            self._hb_stop.set()
            if self._hb_thread is not None and self._hb_thread is not threading.current_thread():
                self._hb_thread.join(1.0)
        self._hb_stop = self._hb_thread = None

    def all_off(self) -> bool:
        """Relays off and telemetry stopped, best effort; never raises. True if acknowledged."""
        ok = False
        for _ in range(2):
            try:
                ok = isinstance(self.request(P.SetRelays(0), timeout=0.3), P.Ack)
                if ok:
                    break
            except Exception:  # noqa: BLE001 - the port may be gone; the firmware watchdog remains
                continue
        try:
            self.send(P.Stream(0))
        except Exception:  # noqa: BLE001
            pass
        return ok

    def close(self, all_off: bool = True) -> None:
        """Relays off (unless told not to), stop the reader, close the port. Idempotent."""
        self.stop_heartbeat()
        if all_off and self._ser is not None and self._lost is None:
            self.all_off()
        self._stop.set()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(1.0)
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # noqa: BLE001
                pass
        self._ser = None

    @property
    def closed(self) -> bool:
        return self._ser is None

    def __enter__(self) -> "RigLink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
