"""Wire protocol of the neck firmware (``firmware/PROTOCOL.md``), pure Python, no I/O.

A frame is::

    A5 5A | VER | TYPE | SEQ | LEN | PAYLOAD[LEN] | CRC16 (LE)

with the CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final
xor) over ``VER .. end of payload``. All multi-byte fields are little-endian.

This module holds the constants, the CRC, frame encoding, a streaming
:class:`FrameDecoder` that resynchronises after garbage, and one dataclass per
message. The numbers mirror ``firmware/src/protocol.h``; the firmware is the
authority and the HIL tests check the two agree.
"""

from __future__ import annotations

import binascii
import enum
import math
import struct
from dataclasses import dataclass
from typing import ClassVar

__all__ = [
    "PROTOCOL_VERSION",
    "SYNC",
    "HEADER_LEN",
    "CRC_LEN",
    "MAX_PAYLOAD",
    "MAX_FRAME_LEN",
    "N_MUSCLES",
    "MsgType",
    "ErrorCode",
    "Fault",
    "Mode",
    "ProtocolError",
    "crc16_ccitt",
    "encode_frame",
    "Frame",
    "FrameDecoder",
    "Hello",
    "SetRelays",
    "SetDuty",
    "Stream",
    "Stop",
    "Heartbeat",
    "Config",
    "ClearFaults",
    "GetStatus",
    "WdtTest",
    "Boot",
    "HelloReply",
    "Ack",
    "Nak",
    "Telemetry",
    "Status",
    "Message",
    "HostMessage",
    "McuMessage",
    "encode",
    "decode_message",
    "ntc_adc_to_celsius",
    "celsius_to_ntc_adc",
    "ACCEL_LSB_PER_G",
    "THERM_CUT_ADC_DEFAULT",
    "THERM_RELEASE_ADC_DEFAULT",
    "THERM_CUT_ADC_MIN",
    "THERM_MAX_CUT_C",
    "GYRO_LSB_PER_DPS",
]

PROTOCOL_VERSION = 1
SYNC = b"\xa5\x5a"
HEADER_LEN = 6
CRC_LEN = 2
MAX_PAYLOAD = 64
MAX_FRAME_LEN = HEADER_LEN + MAX_PAYLOAD + CRC_LEN
N_MUSCLES = 3

#: Over-temperature cut of fitted thermistors (firmware/src/config.h): the default after reset,
#: and the hottest cut a host may set with CONFIG (ADC counts of the documented NTC divider).
THERM_CUT_ADC_DEFAULT = 51  # 110 C
THERM_RELEASE_ADC_DEFAULT = 67  # 100 C
THERM_CUT_ADC_MIN = 14  # ~167 C: the firmware's maximum
THERM_MAX_CUT_C = 167.0
THERM_HYSTERESIS_C = 10.0

#: Scale of the raw IMU values at the firmware's ranges (+-4 g, +-500 deg/s).
ACCEL_LSB_PER_G = 8192.0
GYRO_LSB_PER_DPS = 65.5


class MsgType(enum.IntEnum):
    """Frame TYPE byte. Host -> MCU below 0x80, MCU -> host from 0x80."""

    HELLO = 0x01
    SET_RELAYS = 0x02
    SET_DUTY = 0x03
    STREAM = 0x04
    STOP = 0x05
    HEARTBEAT = 0x06
    CONFIG = 0x07
    CLEAR_FAULTS = 0x08
    GET_STATUS = 0x09
    WDT_TEST = 0x0A
    BOOT = 0x80
    HELLO_REPLY = 0x81
    ACK = 0x82
    NAK = 0x83
    TELEMETRY = 0x84
    STATUS = 0x85


class ErrorCode(enum.IntEnum):
    """NAK error codes."""

    BAD_LENGTH = 1
    UNKNOWN_TYPE = 2
    BAD_VALUE = 3
    BAD_VERSION = 4


class Fault(enum.IntFlag):
    """Fault flag bits of TELEMETRY (u16)."""

    HEARTBEAT_LOST = 1 << 0  # latched; cleared by the next valid frame
    IMU_MISSING = 1 << 1  # live: 0x68 does not ACK (address or data NACK)
    IMU_BAD_ID = 1 << 2  # live: WHO_AM_I != 0x68
    IMU_READ = 1 << 3  # live: read/config failure or bus timeout
    ONTIME_LOCKOUT = 1 << 4  # live: a muscle is locked out after the on-time cap
    DUTY_LIMIT = 1 << 5  # live: a muscle is held off by the sustained-duty limiter
    OVERTEMP = 1 << 6  # live: a muscle is cut by over-temperature
    THERM_SENSOR = 1 << 7  # live: a fitted thermistor reads open
    WDT_RESET = 1 << 8  # latched since boot: the last reset was the AVR watchdog
    SAFETY_TRIP = 1 << 9  # latched: firmware forced a muscle off since CLEAR_FAULTS
    TX_OVERFLOW = 1 << 10  # latched: a telemetry frame was dropped

    @classmethod
    def imu_any(cls) -> "Fault":
        return cls.IMU_MISSING | cls.IMU_BAD_ID | cls.IMU_READ


class Mode(enum.IntEnum):
    """Per-muscle command mode reported in TELEMETRY."""

    OFF = 0
    DIRECT = 1
    DUTY = 2


class ProtocolError(ValueError):
    """A frame or payload that does not follow the protocol."""


# ---------------------------------------------------------------------------
# CRC and framing
# ---------------------------------------------------------------------------


def crc16_ccitt(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, MSB first, no final xor -- the firmware's
    ``_crc_xmodem_update`` chain from 0xFFFF (``tests/test_rig_protocol.py`` checks it bit for
    bit against that routine; the HIL tests against the firmware itself).

    ``crc16_ccitt(b"123456789") == 0x29B1`` (the catalogue check value).
    """
    return binascii.crc_hqx(bytes(data), crc)


def encode_frame(msg_type: int, seq: int, payload: bytes = b"", version: int = PROTOCOL_VERSION) -> bytes:
    """Build one frame. ``version`` is a parameter only so tests can forge bad frames."""
    if not 0 <= msg_type <= 0xFF or not 0 <= seq <= 0xFF or not 0 <= version <= 0xFF:
        raise ProtocolError("type, seq and version must fit in a byte")
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((version, msg_type, seq, len(payload))) + bytes(payload)
    return SYNC + body + struct.pack("<H", crc16_ccitt(body))


@dataclass(frozen=True)
class Frame:
    """A CRC-checked frame (its payload not yet interpreted)."""

    version: int
    type: int
    seq: int
    payload: bytes


class FrameDecoder:
    """Streaming frame decoder.

    Feed it arbitrary chunks of the byte stream; it returns complete,
    CRC-valid frames. On a framing error (length out of range, CRC mismatch)
    it drops only the first byte and rescans, so a genuine frame that starts
    inside garbage or inside a truncated frame is still found -- the same rule
    as the firmware's parser.

    Counters: ``frames`` (good), ``bad_frames`` (CRC or length errors),
    ``garbage_bytes`` (bytes skipped while hunting for a sync pattern,
    including those of bad frames).
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.frames = 0
        self.bad_frames = 0
        self.garbage_bytes = 0

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()

    def flush_partial(self) -> list[Frame]:
        """Give up on a held partial frame (e.g. the line went quiet): count it
        as bad, drop its first byte and rescan the rest, returning any frames
        that were hidden in it. Mirrors the firmware's stale-frame timeout."""
        if not self._buf:
            return []
        self.bad_frames += 1
        self.garbage_bytes += 1
        rest = bytes(self._buf[1:])
        self._buf.clear()
        return self.feed(rest)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        self._buf.extend(data)
        out: list[Frame] = []
        buf = self._buf
        while True:
            i = buf.find(SYNC[0])
            if i < 0:
                self.garbage_bytes += len(buf)
                buf.clear()
                return out
            if i:
                self.garbage_bytes += i
                del buf[:i]
            if len(buf) < 2:
                return out
            if buf[1] != SYNC[1]:
                self.garbage_bytes += 1
                del buf[:1]
                continue
            if len(buf) < HEADER_LEN:
                return out
            plen = buf[5]
            if plen > MAX_PAYLOAD:
                self.bad_frames += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            total = HEADER_LEN + plen + CRC_LEN
            if len(buf) < total:
                return out
            (crc_rx,) = struct.unpack_from("<H", buf, HEADER_LEN + plen)
            if crc16_ccitt(memoryview(buf)[2 : HEADER_LEN + plen]) != crc_rx:
                self.bad_frames += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            out.append(Frame(buf[2], buf[3], buf[4], bytes(buf[HEADER_LEN : HEADER_LEN + plen])))
            self.frames += 1
            del buf[:total]


# ---------------------------------------------------------------------------
# Messages
# ---------------------------------------------------------------------------


def _check_len(cls_name: str, payload: bytes, n: int) -> None:
    if len(payload) != n:
        raise ProtocolError(f"{cls_name} payload must be {n} bytes, got {len(payload)}")


@dataclass(frozen=True)
class Hello:
    """Ask for versions and configuration (reply: :class:`HelloReply`)."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO

    def payload(self) -> bytes:
        return b""

    @classmethod
    def from_payload(cls, p: bytes) -> "Hello":
        _check_len(cls.__name__, p, 0)
        return cls()


@dataclass(frozen=True)
class SetRelays:
    """Switch the relays directly: bit k = muscle k on. Clears any duty command.

    The payload repeats the mask inverted so that a single corrupted byte can
    never turn a relay on even if it slipped past the CRC.
    """

    TYPE: ClassVar[MsgType] = MsgType.SET_RELAYS
    mask: int

    def __post_init__(self) -> None:
        if not 0 <= self.mask <= 0x07:
            raise ProtocolError(f"relay mask must be 0..7, got {self.mask}")

    def payload(self) -> bytes:
        return bytes((self.mask, self.mask ^ 0xFF))

    @classmethod
    def from_payload(cls, p: bytes) -> "SetRelays":
        _check_len(cls.__name__, p, 2)
        if p[0] ^ 0xFF != p[1]:
            raise ProtocolError("SET_RELAYS complement byte mismatch")
        return cls(p[0])


@dataclass(frozen=True)
class SetDuty:
    """Time-proportional switching: per-muscle duty in permille (0..1000) of the
    firmware's duty window (1000 ms). The firmware clamps to its maximum (800)."""

    TYPE: ClassVar[MsgType] = MsgType.SET_DUTY
    duties: tuple[int, int, int]

    def __post_init__(self) -> None:
        d = tuple(int(x) for x in self.duties)
        if len(d) != N_MUSCLES or any(not 0 <= x <= 1000 for x in d):
            raise ProtocolError(f"duties must be three values in 0..1000, got {self.duties!r}")
        object.__setattr__(self, "duties", d)

    def payload(self) -> bytes:
        return struct.pack("<3H", *self.duties)

    @classmethod
    def from_payload(cls, p: bytes) -> "SetDuty":
        _check_len(cls.__name__, p, 6)
        return cls(struct.unpack("<3H", p))


@dataclass(frozen=True)
class Stream:
    """Telemetry rate in Hz (0 = off, at most 100)."""

    TYPE: ClassVar[MsgType] = MsgType.STREAM
    rate_hz: int

    def __post_init__(self) -> None:
        if not 0 <= self.rate_hz <= 255:
            raise ProtocolError(f"rate must fit in a byte, got {self.rate_hz}")

    def payload(self) -> bytes:
        return bytes((self.rate_hz,))

    @classmethod
    def from_payload(cls, p: bytes) -> "Stream":
        _check_len(cls.__name__, p, 1)
        return cls(p[0])


class _NoPayload:
    """A message without payload: encodes to nothing, decodes only from nothing."""

    def payload(self) -> bytes:
        return b""

    @classmethod
    def from_payload(cls, p: bytes):
        _check_len(cls.__name__, p, 0)
        return cls()


@dataclass(frozen=True)
class Stop(_NoPayload):
    """All relays off, all commands cleared, streaming off."""

    TYPE: ClassVar[MsgType] = MsgType.STOP


@dataclass(frozen=True)
class Heartbeat(_NoPayload):
    """Keeps the link watchdog fed (any valid frame does too)."""

    TYPE: ClassVar[MsgType] = MsgType.HEARTBEAT


@dataclass(frozen=True)
class Config:
    """Which thermistors are fitted (bit k = muscle k), enabling their over-temperature cut,
    and optionally where the cut lies.

    ``cut_adc``/``release_adc`` (both or neither): a fitted muscle is cut when its NTC reads
    ``<= cut_adc`` (hot reads low) and released at ``>= release_adc``. Omitted: the firmware
    defaults (110 C / 100 C). The firmware refuses (NAK ``BAD_VALUE``) a cut hotter than
    ``THERM_CUT_ADC_MIN`` (~167 C), a hysteresis under 2 counts or a release at the
    open-sensor reading. :meth:`for_cutoff` builds one from temperatures.
    """

    TYPE: ClassVar[MsgType] = MsgType.CONFIG
    thermistor_mask: int
    cut_adc: int | None = None
    release_adc: int | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.thermistor_mask <= 0x07:
            raise ProtocolError(f"thermistor mask must be 0..7, got {self.thermistor_mask}")
        if (self.cut_adc is None) != (self.release_adc is None):
            raise ProtocolError("give both cut_adc and release_adc, or neither")
        if self.cut_adc is not None:
            for name in ("cut_adc", "release_adc"):
                v = getattr(self, name)
                if not (isinstance(v, int) and 0 <= v <= 0xFFFF):
                    raise ProtocolError(f"{name} must be an integer ADC count, got {v!r}")

    @classmethod
    def for_cutoff(cls, thermistor_mask: int, cutoff_C: float,
                   hysteresis_C: float = THERM_HYSTERESIS_C) -> "Config":
        """Cut at ``cutoff_C`` and release ``hysteresis_C`` below it (documented divider).
        Raises :class:`ProtocolError` above the firmware's maximum (:data:`THERM_MAX_CUT_C`)."""
        if not (math.isfinite(cutoff_C) and cutoff_C <= THERM_MAX_CUT_C):
            raise ProtocolError(f"over-temperature cut {cutoff_C} C is above the firmware's "
                                f"maximum of {THERM_MAX_CUT_C:.0f} C (THERM_CUT_ADC_MIN = "
                                f"{THERM_CUT_ADC_MIN} counts)")
        if not hysteresis_C > 0:
            raise ProtocolError(f"hysteresis must be > 0 C, got {hysteresis_C}")
        # Hot reads low: cut at the count the cutoff maps to or below (rounded so the cut is
        # within half a count, ~1.5 C at 160 C, of the asked temperature).
        cut = max(THERM_CUT_ADC_MIN, int(round(celsius_to_ntc_adc(cutoff_C))))
        release = max(cut + 2, int(round(celsius_to_ntc_adc(cutoff_C - hysteresis_C))))
        return cls(thermistor_mask, cut, release)

    def payload(self) -> bytes:
        if self.cut_adc is None:
            return bytes((self.thermistor_mask,))
        return struct.pack("<BHH", self.thermistor_mask, self.cut_adc, self.release_adc)

    @classmethod
    def from_payload(cls, p: bytes) -> "Config":
        if len(p) == 5:
            mask, cut, rel = struct.unpack("<BHH", p)
            return cls(mask, cut, rel)
        _check_len(cls.__name__, p, 1)
        return cls(p[0])


@dataclass(frozen=True)
class ClearFaults(_NoPayload):
    """Clear the latched fault bits (live ones stay while their cause lasts)."""

    TYPE: ClassVar[MsgType] = MsgType.CLEAR_FAULTS


@dataclass(frozen=True)
class GetStatus(_NoPayload):
    """Ask for one :class:`Status` frame now (its header SEQ echoes this frame's)."""

    TYPE: ClassVar[MsgType] = MsgType.GET_STATUS


@dataclass(frozen=True)
class WdtTest:
    """Watchdog self-test: the firmware switches everything off, ACKs, then hangs
    until the AVR watchdog resets it (a BOOT frame follows ~0.5 s later)."""

    TYPE: ClassVar[MsgType] = MsgType.WDT_TEST
    MAGIC: ClassVar[bytes] = b"WDT!"

    def payload(self) -> bytes:
        return self.MAGIC

    @classmethod
    def from_payload(cls, p: bytes) -> "WdtTest":
        _check_len(cls.__name__, p, 4)
        if p != cls.MAGIC:
            raise ProtocolError("WDT_TEST magic mismatch")
        return cls()


@dataclass(frozen=True)
class Boot:
    """Sent once after every reset."""

    TYPE: ClassVar[MsgType] = MsgType.BOOT
    protocol_version: int
    fw_version: tuple[int, int, int]
    reset_flags: int  # MCUSR at boot: bit0 PORF, 1 EXTRF, 2 BORF, 3 WDRF (0 behind a bootloader)
    watchdog_reset: bool
    wdt_trips: int

    @classmethod
    def from_payload(cls, p: bytes) -> "Boot":
        _check_len(cls.__name__, p, 8)
        pv, a, b, c, rf, wd, trips = struct.unpack("<BBBBBBH", p)
        return cls(pv, (a, b, c), rf, bool(wd & 1), trips)


@dataclass(frozen=True)
class HelloReply:
    """Versions and the firmware's configuration (every safety number)."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO_REPLY
    protocol_version: int
    fw_version: tuple[int, int, int]
    relay_pins: tuple[int, int, int]
    thermistor_mask: int
    duty_window_ms: int
    duty_max_permille: int
    heartbeat_timeout_ms: int
    ontime_cap_ms: int
    lockout_ms: int
    duty_bucket_cap_ms: int
    duty_bucket_drain: int
    stream_max_hz: int
    imu_read_hz: int
    imu_accel_config: int
    imu_gyro_config: int
    imu_dlpf_config: int
    therm_cut_adc: int
    therm_release_adc: int
    therm_open_adc: int
    reset_flags: int

    _FMT: ClassVar[str] = "<BBBBBBBBHHHHHHBBBBBBHHHB"

    @classmethod
    def from_payload(cls, p: bytes) -> "HelloReply":
        _check_len(cls.__name__, p, struct.calcsize(cls._FMT))
        v = struct.unpack(cls._FMT, p)
        return cls(
            protocol_version=v[0],
            fw_version=(v[1], v[2], v[3]),
            relay_pins=(v[4], v[5], v[6]),
            thermistor_mask=v[7],
            duty_window_ms=v[8],
            duty_max_permille=v[9],
            heartbeat_timeout_ms=v[10],
            ontime_cap_ms=v[11],
            lockout_ms=v[12],
            duty_bucket_cap_ms=v[13],
            duty_bucket_drain=v[14],
            stream_max_hz=v[15],
            imu_read_hz=v[16],
            imu_accel_config=v[17],
            imu_gyro_config=v[18],
            imu_dlpf_config=v[19],
            therm_cut_adc=v[20],
            therm_release_adc=v[21],
            therm_open_adc=v[22],
            reset_flags=v[23],
        )


@dataclass(frozen=True)
class Ack:
    """Command accepted. ``refused_mask`` (info bits 0-2): muscles that stayed off
    because a safety hold is active; ``clamped_mask`` (info bits 4-6): duties
    reduced to the firmware maximum."""

    TYPE: ClassVar[MsgType] = MsgType.ACK
    cmd_type: int
    info: int

    @property
    def refused_mask(self) -> int:
        return self.info & 0x07

    @property
    def clamped_mask(self) -> int:
        return (self.info >> 4) & 0x07

    @classmethod
    def from_payload(cls, p: bytes) -> "Ack":
        _check_len(cls.__name__, p, 2)
        return cls(p[0], p[1])


@dataclass(frozen=True)
class Nak:
    """Command rejected (never acted on)."""

    TYPE: ClassVar[MsgType] = MsgType.NAK
    cmd_type: int
    error: int

    @property
    def error_code(self) -> ErrorCode | int:
        try:
            return ErrorCode(self.error)
        except ValueError:
            return self.error

    @classmethod
    def from_payload(cls, p: bytes) -> "Nak":
        _check_len(cls.__name__, p, 2)
        return cls(p[0], p[1])


@dataclass(frozen=True)
class Telemetry:
    """One streamed telemetry sample (header SEQ = the MCU's frame counter)."""

    TYPE: ClassVar[MsgType] = MsgType.TELEMETRY
    seq: int  # u16, +1 per telemetry frame actually sent
    t_ms: int  # MCU millis()
    relays: int  # actual pin states read back, bit k = muscle k
    blocked: int  # bit k = muscle k held off by a safety hold
    modes: tuple[Mode, Mode, Mode]
    stream_hz: int
    duties: tuple[int, int, int]  # permille applied (DIRECT on = 1000)
    accel: tuple[int, int, int]  # raw int16, 8192 LSB/g
    imu_temp: int  # raw int16: T = raw/340 + 36.53 C
    gyro: tuple[int, int, int]  # raw int16, 65.5 LSB/(deg/s)
    thermistors: tuple[int, int, int]  # raw ADC 0..1023
    faults: Fault
    bad_frames: int
    wdt_trips: int
    imu_errors: int
    thermistor_mask: int

    _FMT: ClassVar[str] = "<HIBBBB3H3hh3h3HHHHHB"

    @property
    def relay_states(self) -> tuple[bool, bool, bool]:
        return tuple(bool(self.relays >> k & 1) for k in range(N_MUSCLES))  # type: ignore[return-value]

    @classmethod
    def from_payload(cls, p: bytes) -> "Telemetry":
        _check_len(cls.__name__, p, struct.calcsize(cls._FMT))
        v = struct.unpack(cls._FMT, p)
        raw_modes = [(v[4] >> (2 * k)) & 3 for k in range(N_MUSCLES)]
        if any(m > Mode.DUTY for m in raw_modes):
            raise ProtocolError(f"invalid mode byte 0x{v[4]:02X}")
        modes = tuple(Mode(m) for m in raw_modes)
        return cls(
            seq=v[0],
            t_ms=v[1],
            relays=v[2],
            blocked=v[3],
            modes=modes,  # type: ignore[arg-type]
            stream_hz=v[5],
            duties=(v[6], v[7], v[8]),
            accel=(v[9], v[10], v[11]),
            imu_temp=v[12],
            gyro=(v[13], v[14], v[15]),
            thermistors=(v[16], v[17], v[18]),
            faults=Fault(v[19]),
            bad_frames=v[20],
            wdt_trips=v[21],
            imu_errors=v[22],
            thermistor_mask=v[23],
        )


@dataclass(frozen=True)
class Status(Telemetry):
    """Reply to GET_STATUS: the TELEMETRY payload, header SEQ echoes the request."""

    TYPE: ClassVar[MsgType] = MsgType.STATUS


#: Messages the host sends.
HostMessage = Hello | SetRelays | SetDuty | Stream | Stop | Heartbeat | Config | ClearFaults | GetStatus | WdtTest
#: Messages the firmware sends.
McuMessage = Boot | HelloReply | Ack | Nak | Telemetry | Status
Message = HostMessage | McuMessage

_BY_TYPE: dict[int, type] = {
    cls.TYPE: cls
    for cls in (
        Hello, SetRelays, SetDuty, Stream, Stop, Heartbeat, Config, ClearFaults, GetStatus, WdtTest,
        Boot, HelloReply, Ack, Nak, Telemetry, Status,
    )
}


def encode(msg: HostMessage, seq: int) -> bytes:
    """Encode a host -> MCU message as a complete frame."""
    return encode_frame(int(msg.TYPE), seq & 0xFF, msg.payload())


def decode_message(frame: Frame) -> Message:
    """Interpret a frame's payload. Raises :class:`ProtocolError` for an unknown
    type, a foreign protocol version or a malformed payload."""
    if frame.version != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {frame.version}, expected {PROTOCOL_VERSION}")
    cls = _BY_TYPE.get(frame.type)
    if cls is None:
        raise ProtocolError(f"unknown message type 0x{frame.type:02X}")
    return cls.from_payload(frame.payload)


# ---------------------------------------------------------------------------
# Thermistor conversion (the firmware reports raw ADC; the host converts)
# ---------------------------------------------------------------------------


def ntc_adc_to_celsius(
    adc: float,
    r_fixed: float = 10_000.0,
    r0: float = 10_000.0,
    beta: float = 3950.0,
    t0_c: float = 25.0,
    adc_max: float = 1023.0,
) -> float:
    """Raw ADC of the documented divider (fixed resistor to +5 V, NTC to GND)
    to degrees C with the beta model. Returns ``nan`` for an open or shorted
    sensor reading (0 or full scale)."""
    if adc <= 0 or adc >= adc_max:
        return math.nan
    r_ntc = r_fixed * adc / (adc_max - adc)
    inv_t = 1.0 / (t0_c + 273.15) + math.log(r_ntc / r0) / beta
    return 1.0 / inv_t - 273.15


def celsius_to_ntc_adc(
    t_c: float,
    r_fixed: float = 10_000.0,
    r0: float = 10_000.0,
    beta: float = 3950.0,
    t0_c: float = 25.0,
    adc_max: float = 1023.0,
) -> float:
    """Inverse of :func:`ntc_adc_to_celsius` (unrounded ADC value)."""
    r_ntc = r0 * math.exp(beta * (1.0 / (t_c + 273.15) - 1.0 / (t0_c + 273.15)))
    return adc_max * r_ntc / (r_ntc + r_fixed)
