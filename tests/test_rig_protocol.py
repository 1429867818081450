"""neck_env.rig.protocol: CRC, framing, messages, streaming decoder (pure Python, fast)."""

import random
import re
import struct
from pathlib import Path

import pytest

from neck_env.rig import protocol as P


def test_crc_known_vectors():
    # CRC-16/CCITT-FALSE catalogue check value.
    assert P.crc16_ccitt(b"123456789") == 0x29B1
    assert P.crc16_ccitt(b"") == 0xFFFF
    assert P.crc16_ccitt(b"A") == 0xB915
    # Incremental use gives the same result.
    assert P.crc16_ccitt(b"56789", P.crc16_ccitt(b"1234")) == 0x29B1


def _crc_xmodem_update(crc: int, data: int) -> int:
    """avr-libc's ``_crc_xmodem_update`` (util/crc16.h), its documented C equivalent: what the
    firmware chains from 0xFFFF over VER..payload (firmware/src/neck_fw.cpp)."""
    crc ^= data << 8
    for _ in range(8):
        crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        crc &= 0xFFFF
    return crc


def test_crc_is_bit_identical_to_the_firmware_routine():
    rng = random.Random(13)
    for n in list(range(0, 40)) + [255, 300]:
        data = bytes(rng.randrange(256) for _ in range(n))
        want = 0xFFFF
        for b in data:
            want = _crc_xmodem_update(want, b)
        assert P.crc16_ccitt(data) == want, data.hex()


def test_frame_layout_is_the_documented_one():
    f = P.encode(P.SetRelays(0b101), seq=7)
    # A5 5A | VER | TYPE | SEQ | LEN | mask ~mask | CRC LE over VER..payload
    assert f[:6] == bytes((0xA5, 0x5A, P.PROTOCOL_VERSION, 0x02, 7, 2))
    assert f[6:8] == bytes((0x05, 0xFA))
    assert struct.unpack("<H", f[8:])[0] == P.crc16_ccitt(f[2:8])
    assert len(P.encode(P.Hello(), 0)) == P.HEADER_LEN + P.CRC_LEN


HOST_MESSAGES = [
    P.Hello(),
    P.SetRelays(0),
    P.SetRelays(7),
    P.SetDuty((0, 500, 1000)),
    P.Stream(0),
    P.Stream(100),
    P.Stop(),
    P.Heartbeat(),
    P.Config(0b101),
    P.Config(0b111, 16, 20),
    P.ClearFaults(),
    P.GetStatus(),
    P.WdtTest(),
]


@pytest.mark.parametrize("msg", HOST_MESSAGES, ids=lambda m: type(m).__name__)
def test_host_messages_round_trip(msg):
    frames = P.FrameDecoder().feed(P.encode(msg, 42))
    assert len(frames) == 1 and frames[0].seq == 42 and frames[0].type == msg.TYPE
    assert P.decode_message(frames[0]) == msg


def _telemetry_payload(**over):
    vals = dict(
        seq=65535, t=123456789, relays=5, blocked=2, modes=0b10_01_00, hz=50,
        duties=(0, 1000, 800), accel=(-32768, 0, 32767), temp=-3920, gyro=(1, -2, 3),
        therm=(0, 512, 1023), faults=0x0303, bad=7, wdt=1, imu_err=9, mask=5,
    )
    vals.update(over)
    return struct.pack(
        "<HIBBBB3H3hh3h3HHHHHB", vals["seq"], vals["t"], vals["relays"], vals["blocked"], vals["modes"],
        vals["hz"], *vals["duties"], *vals["accel"], vals["temp"], *vals["gyro"], *vals["therm"],
        vals["faults"], vals["bad"], vals["wdt"], vals["imu_err"], vals["mask"],
    )


def test_mcu_messages_decode():
    p = _telemetry_payload()
    assert len(p) == 45
    t = P.decode_message(P.FrameDecoder().feed(P.encode_frame(P.MsgType.TELEMETRY, 3, p))[0])
    assert type(t) is P.Telemetry
    assert t.seq == 65535 and t.t_ms == 123456789
    assert t.relay_states == (True, False, True)
    assert t.modes == (P.Mode.OFF, P.Mode.DIRECT, P.Mode.DUTY)
    assert t.duties == (0, 1000, 800) and t.accel == (-32768, 0, 32767) and t.gyro == (1, -2, 3)
    assert t.imu_temp == -3920 and t.thermistors == (0, 512, 1023)
    assert t.faults == P.Fault.HEARTBEAT_LOST | P.Fault.IMU_MISSING | P.Fault.WDT_RESET | P.Fault.SAFETY_TRIP
    s = P.decode_message(P.Frame(P.PROTOCOL_VERSION, P.MsgType.STATUS, 9, p))
    assert type(s) is P.Status and s.t_ms == t.t_ms

    ack = P.decode_message(P.Frame(1, P.MsgType.ACK, 1, bytes((P.MsgType.SET_DUTY, 0x21))))
    assert ack == P.Ack(P.MsgType.SET_DUTY, 0x21) and ack.refused_mask == 1 and ack.clamped_mask == 2
    nak = P.decode_message(P.Frame(1, P.MsgType.NAK, 1, bytes((0x3C, 2))))
    assert nak.error_code == P.ErrorCode.UNKNOWN_TYPE
    boot = P.decode_message(P.Frame(1, P.MsgType.BOOT, 0, bytes((1, 1, 0, 0, 8, 1, 3, 0))))
    assert boot == P.Boot(1, (1, 0, 0), 8, True, 3)


def test_decode_message_rejects_bad_frames():
    with pytest.raises(P.ProtocolError):
        P.decode_message(P.Frame(2, P.MsgType.HELLO, 0, b""))  # foreign version
    with pytest.raises(P.ProtocolError):
        P.decode_message(P.Frame(1, 0x3C, 0, b""))  # unknown type
    with pytest.raises(P.ProtocolError):
        P.decode_message(P.Frame(1, P.MsgType.ACK, 0, b"\x01"))  # short payload
    with pytest.raises(P.ProtocolError):
        P.decode_message(P.Frame(1, P.MsgType.SET_RELAYS, 0, b"\x07\x00"))  # complement
    with pytest.raises(P.ProtocolError):
        P.decode_message(P.Frame(1, P.MsgType.TELEMETRY, 0, _telemetry_payload(modes=0b11)))


def test_message_constructors_validate():
    for bad in (lambda: P.SetRelays(8), lambda: P.SetDuty((0, 0, 1001)), lambda: P.SetDuty((0, 0)),
                lambda: P.Config(9), lambda: P.Stream(256)):
        with pytest.raises(P.ProtocolError):
            bad()
    with pytest.raises(P.ProtocolError):
        P.encode_frame(1, 0, bytes(65))


def test_decoder_resyncs_after_garbage_and_counts_bad_frames():
    rng = random.Random(7)
    msgs = [P.SetDuty((rng.randrange(1001), 0, 5)) for _ in range(50)]
    stream = bytearray()
    for i, m in enumerate(msgs):
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 20)))  # noise
        if i % 5 == 0:  # a corrupted copy first
            bad = bytearray(P.encode(m, i))
            bad[-1] ^= 0x40
            stream += bad
        if i % 7 == 0:  # a truncated frame first
            stream += P.encode(m, i)[:5]
        stream += P.encode(m, i)
    dec = P.FrameDecoder()
    got = []
    # Byte-wise and in odd chunks: framing must not depend on read boundaries.
    pos = 0
    while pos < len(stream):
        n = rng.choice((1, 2, 3, 17, 64))
        got += dec.feed(stream[pos : pos + n])
        pos += n
    decoded = [P.decode_message(f) for f in got]
    assert decoded == msgs
    assert [f.seq for f in got] == list(range(50))
    assert dec.bad_frames >= 10  # every corrupted copy was counted
    assert dec.garbage_bytes > 0 and dec.frames == 50


def test_decoder_handles_oversized_length_and_partial_flush():
    dec = P.FrameDecoder()
    good = P.encode(P.Hello(), 5)
    assert dec.feed(P.SYNC + bytes((1, 1, 0, 200)) + good) == [P.FrameDecoder().feed(good)[0]]
    assert dec.bad_frames == 1
    # A partial frame waits; flushing it recovers a frame hidden inside.
    dec = P.FrameDecoder()
    assert dec.feed(P.SYNC + bytes((1, 2, 0, 30)) + good) == []
    assert dec.pending > 0
    assert dec.flush_partial() == [P.Frame(1, P.MsgType.HELLO, 5, b"")]
    assert dec.bad_frames == 1 and dec.pending == 0


def test_every_single_bit_flip_is_caught():
    frame = P.encode(P.SetRelays(7), 3)
    for i in range(len(frame) * 8):
        b = bytearray(frame)
        b[i // 8] ^= 1 << (i % 8)
        assert P.FrameDecoder().feed(bytes(b)) == [], f"bit {i} flip accepted"


def test_thermistor_conversion_matches_the_documented_thresholds():
    assert P.celsius_to_ntc_adc(25.0) == pytest.approx(511.5)
    assert P.celsius_to_ntc_adc(110.0) == pytest.approx(51.4, abs=0.1)
    assert P.celsius_to_ntc_adc(100.0) == pytest.approx(66.7, abs=0.1)
    for t in (0.0, 37.0, 90.0, 150.0):
        assert P.ntc_adc_to_celsius(P.celsius_to_ntc_adc(t)) == pytest.approx(t, abs=1e-9)
    assert P.ntc_adc_to_celsius(0) != P.ntc_adc_to_celsius(0)  # nan: shorted
    assert P.ntc_adc_to_celsius(1023) != P.ntc_adc_to_celsius(1023)  # nan: open


def test_python_constants_match_the_firmware_header():
    """protocol.py mirrors firmware/src/protocol.h; catch drift without a toolchain."""
    import re
    from pathlib import Path

    header = Path(__file__).resolve().parents[1] / "firmware" / "src" / "protocol.h"
    if not header.is_file():
        pytest.skip("firmware sources not present")
    text = header.read_text()
    consts = {m[0]: int(m[1], 0) for m in re.findall(r"\b(\w+)\s*=\s*(0x[0-9A-Fa-f]+|\d+)u?\b", text)}
    shifts = {m[0]: 1 << int(m[1]) for m in re.findall(r"\b(FAULT_\w+)\s*=\s*1u\s*<<\s*(\d+)", text)}
    assert int(re.search(r"#define PROTOCOL_VERSION (\d+)", text)[1]) == P.PROTOCOL_VERSION
    assert int(re.search(r"#define FRAME_MAX_PAYLOAD (\d+)", text)[1]) == P.MAX_PAYLOAD
    for t in P.MsgType:
        assert consts[f"MSG_{t.name}"] == t.value, t
    for e in P.ErrorCode:
        assert consts[f"ERR_{e.name}"] == e.value, e
    assert {k[len("FAULT_"):]: v for k, v in shifts.items()} == {f.name: f.value for f in P.Fault}


def test_config_cut_threshold_from_temperature_and_firmware_maximum():
    c = P.Config.for_cutoff(0b111, 160.0)
    # 160 C -> 16.2 counts of the 10k/beta-3950 divider; released 10 C lower (150 C, 20 counts)
    assert (c.cut_adc, c.release_adc) == (16, 20)
    assert P.ntc_adc_to_celsius(c.cut_adc) == pytest.approx(160.0, abs=1.5)
    assert len(c.payload()) == 5 and len(P.Config(0b111).payload()) == 1
    with pytest.raises(P.ProtocolError, match="maximum"):
        P.Config.for_cutoff(0b001, 180.0)
    with pytest.raises(P.ProtocolError, match="maximum"):
        P.Config.for_cutoff(0b001, float("inf"))
    with pytest.raises(P.ProtocolError, match="both"):
        P.Config(0b001, 16)
    # the firmware's limits as the header states them
    text = (Path(__file__).resolve().parents[1] / "firmware" / "src" / "config.h").read_text()
    assert int(re.search(r"#define THERM_CUT_ADC_MIN (\d+)U", text)[1]) == P.THERM_CUT_ADC_MIN
    assert int(re.search(r"#define THERM_CUT_ADC (\d+)U", text)[1]) == P.THERM_CUT_ADC_DEFAULT
    assert P.ntc_adc_to_celsius(P.THERM_CUT_ADC_MIN) == pytest.approx(P.THERM_MAX_CUT_C, abs=0.5)
