"""A Python stand-in for the neck firmware, reachable as a pyserial URL (``socket://...``).

Fast unit tests of the host side (link, hardware env, CLI) run against it without simavr. It
speaks the protocol of ``firmware/PROTOCOL.md`` (frames, replies echoing SEQ, telemetry at the
requested rate, SET_RELAYS / SET_DUTY with the 1 s window, the 250 ms heartbeat watchdog) and
can misbehave on request: vanish (the port goes away), fall silent, send garbage or truncated
frames, restart (a BOOT frame), report IMU faults, answer with another protocol version.
It is not a model of the firmware's safety features -- the HIL tests check the real ones.
"""

from __future__ import annotations

import socket
import struct
import threading
import time

from neck_env.rig import protocol as P

TELEMETRY_FMT = "<HIBBBB3H3hh3h3HHHHHB"
HELLO_FMT = "<BBBBBBBBHHHHHHBBBBBBHHHB"
THERM_OPEN_ADC = 1015  # what HELLO reports: a fitted NTC reading this or above is open


class FakeFirmware:
    """Serve one host connection at a time on ``self.url``; see the module docstring."""

    HEARTBEAT_S = 0.25  # host silence that switches all off (firmware: HEARTBEAT_TIMEOUT_MS)

    def __init__(self, protocol_version: int = P.PROTOCOL_VERSION, imu_faults: int = 0,
                 accel: tuple[int, int, int] = (0, 0, 8192), answer: bool = True) -> None:
        self.protocol_version = protocol_version
        self.imu_faults = imu_faults
        self.accel = accel
        self.answer = answer  # False: swallow everything (a board without this firmware)
        self.silent = False  # True: stop sending anything (hung MCU)
        self.relays = 0
        self.duties = [0, 0, 0]
        self.modes = [P.Mode.OFF] * 3
        self.stream_hz = 0
        self.therm_mask = 0
        self.therm_adc = [512, 512, 512]  # raw NTC readings (512: 25 C; 1023: an open sensor)
        self.bad_frames = 0
        self.heartbeat_trips = 0
        self.received: list[P.Message] = []
        self.relay_on_log: list[tuple[float, int]] = []  # (monotonic time, mask) on changes
        self.telemetry_log: list[float] = []  # monotonic time of every telemetry frame sent
        self._t0 = time.monotonic()
        self._last_valid = time.monotonic()
        self._armed = False
        self._tx_seq = 0
        self._tel_seq = 0
        self._lock = threading.Lock()
        self._conn: socket.socket | None = None
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(("127.0.0.1", 0))
        self._srv.listen(1)
        self._srv.settimeout(0.05)
        self.url = f"socket://127.0.0.1:{self._srv.getsockname()[1]}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="fake-firmware", daemon=True)
        self._thread.start()

    # -- time and relays ------------------------------------------------------------------------
    def millis(self) -> int:
        return int((time.monotonic() - self._t0) * 1000)

    def telemetry_sent_since(self, t: float) -> int:
        """How many telemetry frames were sent after monotonic time `t`."""
        return sum(1 for s in list(self.telemetry_log) if s > t)

    def _update_relays(self) -> None:
        now = self.millis()
        mask = 0
        for k in range(3):
            if self.modes[k] == P.Mode.DIRECT or (self.modes[k] == P.Mode.DUTY
                                                   and now % 1000 < self.duties[k]):
                mask |= 1 << k
        if mask != self.relays:
            self.relays = mask
            self.relay_on_log.append((time.monotonic(), mask))

    def _all_off(self) -> None:
        self.modes = [P.Mode.OFF] * 3
        self.duties = [0, 0, 0]
        self._update_relays()

    # -- sending --------------------------------------------------------------------------------
    def _send(self, msg_type: int, seq: int, payload: bytes) -> None:
        self.send_raw(P.encode_frame(msg_type, seq, payload))

    def send_raw(self, data: bytes) -> None:
        """Bytes to the host as they are (garbage, truncated frames, ...)."""
        conn = self._conn
        if conn is not None:
            try:
                conn.sendall(data)
            except OSError:
                pass

    def _status_payload(self) -> bytes:
        with self._lock:
            imu_ok = not self.imu_faults
            accel = self.accel if imu_ok else (0, 0, 0)
            faults = self.imu_faults | (P.Fault.HEARTBEAT_LOST if self.heartbeat_trips else 0)
            if any(self.therm_mask >> k & 1 and a >= THERM_OPEN_ADC for k, a in enumerate(self.therm_adc)):
                faults |= P.Fault.THERM_SENSOR  # as the firmware: a fitted sensor reads open
            modes = sum(int(m) << (2 * k) for k, m in enumerate(self.modes))
            self._tel_seq = (self._tel_seq + 1) & 0xFFFF
            return struct.pack(TELEMETRY_FMT, self._tel_seq, self.millis() & 0xFFFFFFFF,
                               self.relays, 0, modes, self.stream_hz, *self.duties, *accel,
                               -3920, 0, 0, 0, *self.therm_adc, int(faults), self.bad_frames, 0,
                               0, self.therm_mask)

    def send_boot(self) -> None:
        """Pretend the MCU restarted: everything off, BOOT frame."""
        with self._lock:
            self._all_off()
            self.stream_hz = 0
            self._t0 = time.monotonic()
        self._send(P.MsgType.BOOT, self._next_tx(), struct.pack("<BBBBBBH", P.PROTOCOL_VERSION,
                                                                1, 1, 0, 0, 1, 1))

    def _next_tx(self) -> int:
        self._tx_seq = (self._tx_seq + 1) & 0xFF
        return self._tx_seq

    # -- receiving --------------------------------------------------------------------------------
    def _handle(self, fr: P.Frame) -> None:
        try:
            msg = P.decode_message(fr)
        except P.ProtocolError:
            self.bad_frames += 1
            return
        if fr.type >= 0x80:
            self.bad_frames += 1
            return
        self.received.append(msg)
        self._last_valid = time.monotonic()
        self._armed = True
        if not self.answer:
            return
        ack = bytes((fr.type, 0))
        with self._lock:
            if isinstance(msg, P.Hello):
                payload = struct.pack(HELLO_FMT, self.protocol_version, 1, 1, 0, 5, 6, 7,
                                      self.therm_mask, 1000, 800, 250, 10000, 10000, 20000, 4,
                                      100, 200, 8, 8, 3, 51, 67, THERM_OPEN_ADC, 0)
                self._send(P.MsgType.HELLO_REPLY, fr.seq, payload)
                return
            if isinstance(msg, P.SetRelays):
                self.modes = [P.Mode.DIRECT if msg.mask >> k & 1 else P.Mode.OFF for k in range(3)]
                self.duties = [1000 if msg.mask >> k & 1 else 0 for k in range(3)]
            elif isinstance(msg, P.SetDuty):
                clamped = 0
                for k, d in enumerate(msg.duties):
                    if d > 800:
                        d, clamped = 800, clamped | (0x10 << k)
                    self.duties[k] = d
                    self.modes[k] = P.Mode.DUTY if d else P.Mode.OFF
                ack = bytes((fr.type, clamped))
            elif isinstance(msg, P.Stream):
                self.stream_hz = msg.rate_hz
            elif isinstance(msg, P.Stop):
                self._all_off()
                self.stream_hz = 0
            elif isinstance(msg, P.Config):
                self.therm_mask = msg.thermistor_mask
            elif isinstance(msg, P.ClearFaults):
                self.heartbeat_trips = 0
            self._update_relays()
        if isinstance(msg, P.GetStatus):
            self._send(P.MsgType.STATUS, fr.seq, self._status_payload())
            return
        self._send(P.MsgType.ACK, fr.seq, ack)

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._srv.accept()
            except (socket.timeout, OSError):
                continue
            conn.settimeout(0.002)
            self._conn = conn
            dec = P.FrameDecoder()
            next_tel = time.monotonic()
            while not self._stop.is_set() and self._conn is conn:
                try:
                    data = conn.recv(4096)
                    if data == b"":
                        break  # the host closed the port
                except socket.timeout:
                    data = b""
                except OSError:
                    break
                if data and not self.silent:
                    for fr in dec.feed(data):
                        self._handle(fr)
                now = time.monotonic()
                with self._lock:
                    self._update_relays()
                    silent_s = now - self._last_valid
                    if self._armed and silent_s > self.HEARTBEAT_S and any(self.modes):
                        self._all_off()  # the heartbeat watchdog
                        self.heartbeat_trips += 1
                if self.stream_hz and not self.silent and now >= next_tel:
                    self._send(P.MsgType.TELEMETRY, self._next_tx(), self._status_payload())
                    self.telemetry_log.append(now)
                    next_tel = max(next_tel, now - 0.5 / self.stream_hz) + 1.0 / self.stream_hz
            try:
                conn.close()
            except OSError:
                pass
            if self._conn is conn:
                self._conn = None

    # -- misbehaviour ---------------------------------------------------------------------------
    def vanish(self) -> None:
        """The port goes away under the host (USB unplugged)."""
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            conn.close()

    def close(self) -> None:
        self._stop.set()
        self.vanish()
        self._thread.join(2.0)
        self._srv.close()

    def __enter__(self) -> "FakeFirmware":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
