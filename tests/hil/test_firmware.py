"""Hardware in the loop: the real firmware ELF on a simulated ATmega328P (simavr),
talked to over a pty with pyserial, with a fake MPU6050, thermistor inputs and
relay pins observed by the harness.

Paced to real time unless a test says otherwise: the firmware's timeouts run on
its own millis(), and a host acting on wall-clock time only sees them right
when simulated time keeps pace. The long safety tests (10 s on-time cap, the
sustained-duty limiter) run unpaced (~5x) with heartbeats injected on simulated
time by the harness, so they cost seconds, not minutes.
"""

from __future__ import annotations

import random
import subprocess
import time

import pytest

from neck_env.rig import protocol as P

pytestmark = pytest.mark.hil

HB = P.encode(P.Heartbeat(), 0)  # for harness-side injection (SEQ is irrelevant)


def _on_intervals(events, muscle):
    """(t_on_us, t_off_us) pairs of one muscle from the harness's relay events."""
    out, t_on = [], None
    for ev in events:
        if ev.muscle != muscle:
            continue
        if ev.on and t_on is None:
            t_on = ev.t_us
        elif not ev.on and t_on is not None:
            out.append((t_on, ev.t_us))
            t_on = None
    return out


def _wait_status(link, pred, timeout: float = 2.0, what: str = "condition"):
    """Poll GET_STATUS until ``pred(status)``; robust against a loaded machine
    (sim time only advances as fast as the harness gets CPU)."""
    deadline = time.monotonic() + timeout
    while True:
        st = link.status(timeout=2.0)
        if pred(st):
            return st
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}; last status {st}")
        time.sleep(0.01)


def _assert_stack_headroom(link, margin: int = 512) -> int:
    """Peak stack (from the lowest SP the harness saw) must leave ``margin``
    bytes between it and the end of static RAM (_end). Returns the peak."""
    nm = subprocess.run(["avr-nm", str(link.h.elf)], capture_output=True, text=True, check=True).stdout
    end = next(int(line.split()[0], 16) & 0xFFFF for line in nm.splitlines() if line.endswith(" _end"))
    peak = 0x8FF - link.h.stats()["sp_min"]
    assert 0x8FF - end - peak >= margin, f"stack peak {peak} B, static end 0x{end:X}"
    return peak


# ---------------------------------------------------------------------------
# Identity, boot
# ---------------------------------------------------------------------------


def test_boot_banner_and_hello_report_versions_and_limits(start_rig):
    link = start_rig()
    boot = link.messages(P.Boot)[0]
    assert boot.protocol_version == P.PROTOCOL_VERSION
    assert not boot.watchdog_reset and boot.wdt_trips == 0

    hello = link.request(P.Hello())
    assert isinstance(hello, P.HelloReply)
    assert hello.protocol_version == P.PROTOCOL_VERSION
    assert hello.fw_version == boot.fw_version and hello.fw_version[0] >= 1
    # The documented configuration (PROTOCOL.md / README.md).
    assert hello.relay_pins == (5, 6, 7)
    assert hello.duty_window_ms == 1000 and hello.duty_max_permille == 800
    assert hello.heartbeat_timeout_ms == 250
    assert hello.ontime_cap_ms == 10_000 and hello.lockout_ms == 10_000
    assert hello.duty_bucket_cap_ms == 20_000 and hello.duty_bucket_drain == 4
    assert hello.stream_max_hz == 100 and hello.imu_read_hz >= 100
    assert hello.therm_cut_adc == 51 and hello.therm_release_adc == 67
    # The cut threshold is the documented 110 C of the 10k/beta-3950 divider.
    assert P.ntc_adc_to_celsius(hello.therm_cut_adc) == pytest.approx(110.0, abs=1.0)
    assert P.ntc_adc_to_celsius(hello.therm_release_adc) == pytest.approx(100.0, abs=1.0)
    assert not link.decode_errors


def test_relays_off_at_boot_and_after_reset(start_rig):
    link = start_rig()
    time.sleep(0.3)
    assert link.h.relay_events == [], "a relay pin went high during boot"
    assert link.h.relay_pins() == (False, False, False)
    st = link.status()
    assert st.relays == 0 and st.modes == (P.Mode.OFF,) * 3

    # Relays on, then the RESET pin: they must drop at once and stay off
    # through the whole boot (no command survives a reset).
    link.start_heartbeat(0.05)
    link.expect_ack(P.SetRelays(0b111))
    assert link.h.relay_pins() == (True, True, True)
    link.stop_heartbeat()
    n_ev, n_boot, mark = len(link.h.relay_events), len(link.messages(P.Boot)), link.mark()
    link.h.reset()
    assert link.h.relay_pins() == (False, False, False)
    assert link.wait_for(lambda r: isinstance(r.msg, P.Boot), timeout=2.0, start=mark) is not None
    time.sleep(0.5)
    assert len(link.messages(P.Boot)) == n_boot + 1
    assert not any(ev.on for ev in link.h.relay_events[n_ev:])
    assert link.status().relays == 0


# ---------------------------------------------------------------------------
# Relays, heartbeat watchdog
# ---------------------------------------------------------------------------


def test_set_relays_drives_the_pins(start_rig):
    link = start_rig()
    link.start_heartbeat(0.05)
    ack = link.expect_ack(P.SetRelays(0b101))
    assert ack.cmd_type == P.MsgType.SET_RELAYS and ack.refused_mask == 0
    # The pins switched before the ACK was sent.
    assert link.h.relay_pins() == (True, False, True)
    assert link.h.wait_relay(0, True, 1.0) and link.h.wait_relay(2, True, 1.0)
    st = link.status()
    assert st.relays == 0b101 and st.modes == (P.Mode.DIRECT, P.Mode.OFF, P.Mode.DIRECT)
    assert st.duties == (1000, 0, 1000)

    n = len(link.h.relay_events)
    link.expect_ack(P.SetRelays(0b010))
    assert link.h.relay_pins() == (False, True, False)
    changes = {(ev.muscle, ev.on) for ev in link.h.relay_events[n:]}
    assert changes == {(0, False), (1, True), (2, False)}

    link.expect_ack(P.Stop())
    assert link.h.relay_pins() == (False, False, False)
    assert link.status().relays == 0


def test_heartbeat_watchdog_switches_off_after_250ms_of_silence(start_rig):
    link = start_rig()
    link.start_heartbeat(0.05)  # well inside the 250 ms timeout
    link.expect_ack(P.SetRelays(0b011))
    time.sleep(1.5)
    assert not any(not ev.on for ev in link.h.relay_events), "relays dropped while heartbeats flowed"
    assert link.h.relay_pins() == (True, True, False)
    assert not (link.status().faults & P.Fault.HEARTBEAT_LOST)

    link.stop_heartbeat()
    # The last frame the firmware hears: its reply carries the MCU time.
    last = link.status()
    off0 = link.h.wait_relay(0, False, timeout=2.0)
    off1 = link.h.wait_relay(1, False, timeout=2.0)
    assert off0 is not None and off1 is not None, "heartbeat watchdog never fired"
    silence_ms = off0.t_us / 1000.0 - last.t_ms
    # millis() ticks every 1.024 ms, so allow a couple of ms either way.
    assert 249 <= silence_ms <= 256, f"relays went off {silence_ms:.1f} ms after the last frame"
    assert off1.t_us == off0.t_us  # one port write switches all three

    st = link.status()  # a valid frame: clears the flag, but the relays stay off
    assert st.faults & P.Fault.SAFETY_TRIP
    assert st.relays == 0 and st.modes == (P.Mode.OFF,) * 3
    # The flag was visible while the link was dead (streamed telemetry would
    # carry it); GET_STATUS itself is a valid frame, so it is already cleared:
    assert not (st.faults & P.Fault.HEARTBEAT_LOST)
    assert not any(ev.on for ev in link.h.relay_events if ev.t_us > off0.t_us)


def test_heartbeat_lost_flag_is_streamed_while_host_is_silent(start_rig):
    link = start_rig()
    link.expect_ack(P.Stream(20))
    link.expect_ack(P.SetRelays(0b001))
    start = link.mark()
    time.sleep(0.6)
    tel = link.messages(P.Telemetry, start)
    assert any(t.faults & P.Fault.HEARTBEAT_LOST for t in tel)
    assert tel[-1].relays == 0 and tel[-1].faults & P.Fault.SAFETY_TRIP
    ack = link.expect_ack(P.Heartbeat())  # next valid frame clears it
    assert ack.cmd_type == P.MsgType.HEARTBEAT
    later = link.mark()
    time.sleep(0.12)
    assert not any(t.faults & P.Fault.HEARTBEAT_LOST for t in link.messages(P.Telemetry, later)[1:])


# ---------------------------------------------------------------------------
# Malformed input
# ---------------------------------------------------------------------------


def test_rejected_frames_get_nak_and_are_counted_never_acted_on(start_rig):
    link = start_rig()
    bad0 = link.status().bad_frames

    def nak_for(raw: bytes, seq: int) -> P.Nak:
        start = link.mark()
        link.send_raw(raw)
        r = link.wait_for(lambda r: r.frame.type == P.MsgType.NAK and r.frame.seq == seq, 1.0, start)
        assert r is not None, f"no NAK for {raw.hex()}"
        return r.msg

    cases = [
        (P.encode_frame(0x3C, 101, b""), P.ErrorCode.UNKNOWN_TYPE),
        (P.encode_frame(P.MsgType.SET_RELAYS, 102, b"\x07"), P.ErrorCode.BAD_LENGTH),
        (P.encode_frame(P.MsgType.SET_RELAYS, 103, b"\x07\xf8", version=2), P.ErrorCode.BAD_VERSION),
        (P.encode_frame(P.MsgType.SET_RELAYS, 104, b"\x07\x00"), P.ErrorCode.BAD_VALUE),  # complement wrong
        (P.encode_frame(P.MsgType.SET_RELAYS, 105, b"\x08\xf7"), P.ErrorCode.BAD_VALUE),  # no muscle 3
        (P.encode_frame(P.MsgType.SET_DUTY, 106, bytes.fromhex("e903" "0000" "0000")), P.ErrorCode.BAD_VALUE),
        (P.encode_frame(P.MsgType.STREAM, 107, b"\x65"), P.ErrorCode.BAD_VALUE),  # 101 Hz
        (P.encode_frame(P.MsgType.WDT_TEST, 108, b"WDT?"), P.ErrorCode.BAD_VALUE),
        (P.encode_frame(P.MsgType.HELLO, 109, b"\x00"), P.ErrorCode.BAD_LENGTH),
    ]
    for raw, code in cases:
        nak = nak_for(raw, raw[4])
        assert nak.error_code == code and nak.cmd_type == raw[3]
    # An MCU->host type coming back (looped line) is counted but not answered.
    start = link.mark()
    link.send_raw(P.encode_frame(P.MsgType.ACK, 110, b"\x02\x00"))
    st = link.status()
    assert not [r for r in link.rx[start:] if r.frame.type == P.MsgType.NAK]
    assert st.bad_frames == bad0 + len(cases) + 1
    assert st.relays == 0 and st.modes == (P.Mode.OFF,) * 3
    assert link.h.relay_events == []


def test_garbage_and_corrupted_frames_never_switch_relays_or_reset(start_rig):
    link = start_rig()
    rng = random.Random(1234)
    t_before = link.status().t_ms
    n_boot = len(link.messages(P.Boot))

    chunks: list[bytes] = []
    for i in range(120):
        kind = i % 4
        good = P.encode(P.SetRelays(0b111), rng.randrange(256))
        if kind == 0:  # line noise
            chunks.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60))))
        elif kind == 1:  # a SET_RELAYS(all on) with one bit flipped anywhere
            b = bytearray(good)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            chunks.append(bytes(b))
        elif kind == 2:  # truncated SET_RELAYS(all on)
            chunks.append(good[: rng.randrange(1, len(good))])
        else:  # sync bytes followed by nonsense, huge LEN
            chunks.append(P.SYNC + bytes((1, 2, 0, rng.randrange(65, 256))) + bytes(rng.randrange(256) for _ in range(8)))
    blob = b"".join(chunks)
    link.send_raw(blob)
    # Let the UART chew through it (~87 us per byte at 115200 baud).
    time.sleep(len(blob) / 11520 + 0.3)

    # Still alive, never rebooted, never switched, garbage counted.
    hello = link.request(P.Hello(), timeout=3.0)
    assert isinstance(hello, P.HelloReply)
    st = link.status()
    assert st.t_ms > t_before
    assert len(link.messages(P.Boot)) == n_boot and link.h.resets == []
    assert st.wdt_trips == 0 and not (st.faults & P.Fault.WDT_RESET)
    assert st.bad_frames >= 60
    assert st.relays == 0 and st.modes == (P.Mode.OFF,) * 3
    assert not any(ev.on for ev in link.h.relay_events)
    assert link.h.relay_pins() == (False, False, False)

    # Resynchronisation: a truncated frame directly followed by a good one.
    trunc = P.encode(P.SetRelays(0b111), 1)[:7]
    start = link.mark()
    seq = link.next_seq()
    link.send_raw(trunc + P.encode(P.Hello(), seq))
    assert link.wait_for(lambda r: isinstance(r.msg, P.HelloReply) and r.frame.seq == seq, 1.0, start)
    # A truncated frame left alone is dropped after the stale timeout (100 ms).
    bad = link.status().bad_frames
    link.send_raw(trunc)
    time.sleep(0.3)
    assert link.status().bad_frames > bad
    assert not any(ev.on for ev in link.h.relay_events)
    _assert_stack_headroom(link)


# ---------------------------------------------------------------------------
# Duty, caps
# ---------------------------------------------------------------------------


def test_duty_command_gives_documented_on_fraction_and_is_clamped(start_rig):
    link = start_rig()
    link.start_heartbeat(0.05)
    ack = link.expect_ack(P.SetDuty((500, 1000, 250)))
    assert ack.clamped_mask == 0b010 and ack.refused_mask == 0
    st = link.status()
    assert st.duties == (500, 800, 250)
    assert st.modes == (P.Mode.DUTY,) * 3
    time.sleep(3.5)
    t_stop = link.h.sim_time_us()
    link.expect_ack(P.Stop())
    link.stop_heartbeat()
    ev = link.h.relay_events
    for muscle, duty in ((0, 500), (1, 800), (2, 250)):
        iv = _on_intervals(ev, muscle)
        # Whole windows only: the first interval may be cut by the command,
        # the last by the STOP.
        full = [(a, b) for a, b in iv[1:] if b < t_stop]
        assert len(full) >= 2, (muscle, iv)
        for a, b in full:
            assert (b - a) / 1000.0 == pytest.approx(duty, abs=3), (muscle, iv)
        starts = [a for a, _ in full]
        for s0, s1 in zip(starts, starts[1:]):
            assert (s1 - s0) / 1000.0 == pytest.approx(1000, abs=3)
    assert link.h.relay_pins() == (False, False, False)


def test_continuous_on_time_cap_and_lockout(start_rig):
    link = start_rig(speed=0)  # unpaced; heartbeats ride on simulated time
    link.via_harness = True
    link.h.inject_every(50, HB, slot=0)
    link.expect_ack(P.SetRelays(0b001), timeout=2.0)
    on = link.h.wait_relay(0, True, timeout=2.0)
    off = link.h.wait_relay(0, False, timeout=20.0)
    assert on and off, "relay never switched / on-time cap never fired"
    on_ms = (off.t_us - on.t_us) / 1000.0
    assert 9_998 <= on_ms <= 10_005, on_ms  # millis() ticks every 1.024 ms

    st = link.status(timeout=2.0)
    assert st.faults & P.Fault.ONTIME_LOCKOUT and st.faults & P.Fault.SAFETY_TRIP
    assert st.blocked == 0b001 and st.relays == 0 and st.modes[0] == P.Mode.OFF

    # Locked out: the command is acknowledged but muscle 0 is refused.
    n = len(link.h.relay_events)
    ack = link.expect_ack(P.SetRelays(0b011), timeout=2.0)
    assert ack.refused_mask == 0b001
    assert link.h.wait_relay(1, True, timeout=2.0, start=n)
    assert link.h.relay_pins()[0] is False
    link.expect_ack(P.SetRelays(0), timeout=2.0)

    # After the 10 s lock-out it may run again.
    t_lock_end_us = off.t_us + 10_000_000
    while link.h.sim_time_us() < t_lock_end_us + 50_000:
        time.sleep(0.1)
    st = link.status(timeout=2.0)
    assert not (st.faults & P.Fault.ONTIME_LOCKOUT) and st.blocked == 0
    n = len(link.h.relay_events)
    assert link.expect_ack(P.SetRelays(0b001), timeout=2.0).refused_mask == 0
    assert link.h.wait_relay(0, True, timeout=2.0, start=n)
    link.expect_ack(P.Stop(), timeout=2.0)


def test_sustained_duty_limiter_trips_on_near_continuous_switching(start_rig):
    """Relay on, with a ~1 ms off blip every 5 s: the continuous-on cap never
    fires, but the long-run duty is ~100 % > 80 %, so the leaky bucket
    (+1/ms on, -4/ms off, cap 20 s) trips after ~20 s of on-time."""
    link = start_rig(speed=0)
    link.via_harness = True
    link.h.inject_every(50, HB, slot=0)
    # The blip pattern itself switches the relay on (first one 5 s from now),
    # so the on-intervals are exactly 5 s of MCU time whatever the host's latency.
    blip = P.encode(P.SetRelays(0), 200) + P.encode(P.SetRelays(0b100), 201)
    link.h.inject_every(5000, blip, slot=1)
    on = link.h.wait_relay(2, True, timeout=10.0)
    assert on is not None
    deadline = time.monotonic() + 30
    trip = None
    while time.monotonic() < deadline:
        st = link.status(timeout=2.0)
        if st.faults & P.Fault.DUTY_LIMIT:
            trip = st
            break
        time.sleep(0.2)
    link.h.inject_every(0, slot=1)
    assert trip is not None, "duty limiter never tripped"
    assert not (trip.faults & P.Fault.ONTIME_LOCKOUT)
    assert trip.blocked == 0b100 and trip.relays == 0
    # It took ~20 s of (nearly continuous) on-time.
    last_off = [ev for ev in link.h.relay_events if ev.muscle == 2 and not ev.on][-1]
    assert 19.5 <= (last_off.t_us - on.t_us) / 1e6 <= 21.0
    # Refused until the bucket drains (20 s / 4 = 5 s of off-time).
    assert link.expect_ack(P.SetRelays(0b100), timeout=2.0).refused_mask == 0b100
    t_free = last_off.t_us + 5_000_000
    while link.h.sim_time_us() < t_free + 50_000:
        time.sleep(0.1)
    assert link.expect_ack(P.SetRelays(0b100), timeout=2.0).refused_mask == 0
    link.expect_ack(P.Stop(), timeout=2.0)


def test_thermistor_over_temperature_cut(start_rig):
    link = start_rig()
    link.start_heartbeat(0.05)
    # Not fitted: a "hot" reading is reported but ignored.
    link.h.set_adc(0, 40)
    link.expect_ack(P.SetRelays(0b001))
    time.sleep(0.1)
    st = link.status()
    assert st.thermistors[0] == 40 and st.relays == 0b001 and not (st.faults & P.Fault.OVERTEMP)

    link.h.set_adc(0, 512)
    link.expect_ack(P.Config(0b001))
    n = len(link.h.relay_events)
    link.h.set_adc(0, 51)  # 110 C: cut after 3 confirming samples (10 ms apart)
    off = link.h.wait_relay(0, False, timeout=1.0, start=n)
    assert off is not None
    st = link.status()
    assert st.faults & P.Fault.OVERTEMP and st.blocked == 0b001 and st.relays == 0
    assert link.expect_ack(P.SetRelays(0b001)).refused_mask == 0b001
    link.h.set_adc(0, 60)  # cooler but above the 100 C release point: still held
    time.sleep(0.1)
    assert link.status().faults & P.Fault.OVERTEMP
    link.h.set_adc(0, 512)
    _wait_status(link, lambda s: not (s.faults & P.Fault.OVERTEMP), timeout=1.0, what="over-temp release")
    assert link.expect_ack(P.SetRelays(0b001)).refused_mask == 0
    assert link.h.relay_pins()[0]

    # An open sensor (fitted) is a fault too: fail safe.
    n = len(link.h.relay_events)
    link.h.set_adc(0, 1023)
    assert link.h.wait_relay(0, False, timeout=1.0, start=n)
    st = link.status()
    assert st.faults & P.Fault.THERM_SENSOR and st.relays == 0
    link.expect_ack(P.Stop())


def test_host_sets_the_over_temperature_cut_within_the_firmware_maximum(start_rig):
    """CONFIG with thresholds: the sim env's 160 C cut on the rig, never above ~167 C."""
    link = start_rig()
    link.start_heartbeat(0.05)
    hello = link.request(P.Hello())
    assert (hello.therm_cut_adc, hello.therm_release_adc) == (51, 67)  # 110 / 100 C defaults
    # Out of range: hotter than the firmware maximum, no hysteresis, release at "open": NAK,
    # and nothing changes.
    for cut, rel in ((P.THERM_CUT_ADC_MIN - 1, 30), (16, 17), (16, 1015), (1015, 1016)):
        r = link.request(P.Config(0b001, cut, rel))
        assert isinstance(r, P.Nak) and r.error == P.ErrorCode.BAD_VALUE, (cut, rel, r)
    assert link.request(P.Hello()).therm_cut_adc == 51
    cfg = P.Config.for_cutoff(0b001, 160.0)
    link.expect_ack(cfg)
    hello = link.request(P.Hello())
    assert (hello.therm_cut_adc, hello.therm_release_adc) == (cfg.cut_adc, cfg.release_adc)

    link.expect_ack(P.SetRelays(0b001))
    link.h.set_adc(0, 51)  # 110 C: the old default cut, now allowed
    time.sleep(0.1)
    st = link.status()
    assert st.relays == 0b001 and not (st.faults & P.Fault.OVERTEMP)
    n = len(link.h.relay_events)
    link.h.set_adc(0, cfg.cut_adc)  # 160 C
    assert link.h.wait_relay(0, False, timeout=1.0, start=n) is not None
    assert link.status().faults & P.Fault.OVERTEMP
    link.h.set_adc(0, cfg.release_adc - 1)  # cooler, not yet 150 C: held
    time.sleep(0.1)
    assert link.status().faults & P.Fault.OVERTEMP
    link.h.set_adc(0, cfg.release_adc)
    _wait_status(link, lambda s: not (s.faults & P.Fault.OVERTEMP), timeout=1.0, what="release")
    # CONFIG with the mask alone restores the defaults.
    link.expect_ack(P.Config(0b001))
    assert link.request(P.Hello()).therm_cut_adc == 51
    link.expect_ack(P.Stop())


# ---------------------------------------------------------------------------
# IMU
# ---------------------------------------------------------------------------


def test_imu_is_configured_and_raw_values_reach_telemetry(start_rig):
    link = start_rig()
    h = link.h
    # the firmware configures the IMU right after BOOT; on a loaded machine the emulator may
    # need longer than a fixed sleep for that, so wait for it (bounded)
    deadline = time.monotonic() + 2.0
    while h.imu_register(0x1C) != 0x08 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert h.imu_register(0x6B) == 0x01  # awake, PLL clock
    assert h.imu_register(0x19) == 4  # 200 Hz sample rate
    assert h.imu_register(0x1A) == 0x03  # DLPF
    assert h.imu_register(0x1B) == 0x08  # +-500 dps
    assert h.imu_register(0x1C) == 0x08  # +-4 g
    st = link.status()
    assert st.accel == (0, 0, 8192) and not (st.faults & P.Fault.imu_any())

    h.set_imu(1234, -2345, 7000, -32768, 32767, -5)
    h.set_imu_temp(-1000)
    # IMU and IMU_TEMP are two harness commands: a read between them is legitimate, so wait
    # for both to have reached the firmware
    st = _wait_status(link, lambda s: s.accel != (0, 0, 8192) and s.imu_temp != -3920,
                      what="new IMU values")
    assert st.accel == (1234, -2345, 7000)
    assert st.gyro == (-32768, 32767, -5)
    assert st.imu_temp == -1000


def test_absent_imu_is_a_fault_and_the_rest_keeps_working(start_rig):
    link = start_rig(imu_absent=True)
    st = link.status()
    assert st.faults & P.Fault.IMU_MISSING
    assert st.accel == (0, 0, 0) and st.gyro == (0, 0, 0)
    # Relays, heartbeat and replies still work.
    link.start_heartbeat(0.05)
    link.expect_ack(P.SetRelays(0b010))
    assert link.h.relay_pins() == (False, True, False)
    assert isinstance(link.request(P.Hello()), P.HelloReply)
    errs = link.status().imu_errors

    # Retries about once a second; plugging it in recovers (it powers up
    # asleep, so this also proves the firmware re-initialises it).
    link.h.set_imu(100, 200, 8000, 1, 2, 3)
    link.h.set_imu_absent(False)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.5:
        st = link.status()
        if not (st.faults & P.Fault.imu_any()):
            break
        time.sleep(0.05)
    assert not (st.faults & P.Fault.imu_any()), st.faults
    st = _wait_status(link, lambda s: s.accel != (0, 0, 0), what="IMU data after re-init")
    assert st.accel == (100, 200, 8000) and st.gyro == (1, 2, 3)
    assert st.imu_errors >= errs

    # Unplugged while running: flagged at the next read (5 ms), stale data dropped. Pulled out
    # in the middle of a transaction it is a short read (IMU_READ); the retry about a second
    # later finds nobody at the address and names it (IMU_MISSING).
    link.h.set_imu_absent(True)
    st = _wait_status(link, lambda s: s.faults & P.Fault.imu_any(), timeout=1.0, what="IMU fault")
    assert st.accel == (0, 0, 0) and st.gyro == (0, 0, 0)
    assert st.relays == 0b010  # the muscles are not the IMU's business
    st = _wait_status(link, lambda s: s.faults & P.Fault.IMU_MISSING, timeout=5.0,
                      what="IMU_MISSING after the retry")
    assert st.accel == (0, 0, 0) and st.relays == 0b010

    # A different chip (WHO_AM_I 0x70) is refused.
    link.h.set_imu_whoami(0x70)
    link.h.set_imu_absent(False)
    _wait_status(link, lambda s: s.faults & P.Fault.IMU_BAD_ID, timeout=2.5, what="IMU_BAD_ID")
    link.expect_ack(P.Stop())


# ---------------------------------------------------------------------------
# Telemetry, watchdog
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("rate", [50, 100])
def test_telemetry_arrives_at_the_requested_rate(start_rig, rate):
    link = start_rig()
    link.start_heartbeat(0.05)
    start = link.mark()
    link.expect_ack(P.Stream(rate))
    time.sleep(2.0)
    link.expect_ack(P.Stream(0))
    tel = link.messages(P.Telemetry, start)
    # Rate on the MCU's clock (exact), and roughly on the host's (paced).
    mcu_rate = (len(tel) - 1) / ((tel[-1].t_ms - tel[0].t_ms) / 1000.0)
    assert mcu_rate == pytest.approx(rate, rel=0.02)
    assert len(tel) == pytest.approx(2.0 * rate, rel=0.15)
    dts = [b.t_ms - a.t_ms for a, b in zip(tel, tel[1:])]
    period = 1000 // rate
    assert sorted(dts)[len(dts) // 2] == period
    assert max(dts) <= period + 2
    seqs = [t.seq for t in tel]
    assert all((b - a) & 0xFFFF == 1 for a, b in zip(seqs, seqs[1:])), "telemetry frames dropped"
    assert all(t.stream_hz == rate for t in tel[:-1])
    assert not any(t.faults & P.Fault.TX_OVERFLOW for t in tel)
    after = link.mark()
    time.sleep(0.2)
    assert len(link.messages(P.Telemetry, after)) <= 1  # stopped
    _assert_stack_headroom(link)


def test_host_and_firmware_crcs_agree_bit_for_bit(start_rig):
    """Every frame the firmware sends carries its CRC (avr-libc ``_crc_xmodem_update``) and the
    host accepts only frames whose CRC matches its own (``binascii.crc_hqx``); every host frame
    is ACKed only if the firmware's CRC matches. Telemetry varies (time, IMU noise), and so do
    the duty commands: hundreds of distinct CRCs, none rejected either way."""
    link = start_rig()
    link.start_heartbeat(0.05)
    start = link.mark()
    link.expect_ack(P.Stream(100))
    rng = random.Random(5)
    for _ in range(40):
        link.expect_ack(P.SetDuty(tuple(rng.randrange(0, 500) for _ in range(3))))
    time.sleep(1.0)
    link.expect_ack(P.SetDuty((0, 0, 0)))
    link.expect_ack(P.Stream(0))
    tel = link.messages(P.Telemetry, start)
    assert len(tel) >= 80
    assert link.decoder.bad_frames == 0 and not link.decode_errors


def test_hardware_watchdog_resets_a_hung_loop(start_rig):
    link = start_rig()
    link.start_heartbeat(0.05)
    link.expect_ack(P.SetRelays(0b110))
    link.stop_heartbeat()
    n_boot, mark, n_ev = len(link.messages(P.Boot)), link.mark(), len(link.h.relay_events)
    t_cmd = link.h.sim_time_us()
    # The self-test hangs loop() with the relays still on: only the watchdog
    # interrupt can switch them off now (the heartbeat check no longer runs).
    ack = link.expect_ack(P.WdtTest())
    assert ack.cmd_type == P.MsgType.WDT_TEST
    t_reset = link.h.wait_reset(timeout=3.0)
    assert t_reset is not None, "the AVR watchdog never reset the MCU"
    offs = [ev for ev in link.h.relay_events[n_ev:] if not ev.on]
    assert {ev.muscle for ev in offs} == {1, 2}
    t_off = max(ev.t_us for ev in offs)
    # WDT period 2048 << 4 cycles of 128 kHz = 256 ms: interrupt (relays off,
    # trip noted), then the reset one period later.
    assert 240_000 <= t_off - t_cmd <= 400_000, t_off - t_cmd  # + host->MCU latency
    assert 240_000 <= t_reset - t_off <= 270_000, t_reset - t_off
    boot = link.wait_for(lambda r: isinstance(r.msg, P.Boot), timeout=2.0, start=mark)
    assert boot is not None
    boots = link.messages(P.Boot)
    assert len(boots) == n_boot + 1
    assert boots[-1].watchdog_reset and boots[-1].wdt_trips == 1
    assert boots[-1].reset_flags & 0x08  # WDRF
    # No boot loop: it stays up, and says why it restarted.
    time.sleep(0.5)
    assert len(link.messages(P.Boot)) == n_boot + 1 and len(link.h.resets) == 1
    st = link.status()
    assert st.faults & P.Fault.WDT_RESET and st.wdt_trips == 1
    assert st.relays == 0 and st.modes == (P.Mode.OFF,) * 3
    link.expect_ack(P.ClearFaults())
    assert not (link.status().faults & P.Fault.WDT_RESET)
    assert not any(ev.on for ev in link.h.relay_events[n_ev:])
