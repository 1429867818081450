"""Hardware in the loop, host + firmware safety: the code a user runs (``HardwareNeckEnv``, the
CLI) on the real firmware ELF in simavr, attacked the way a real rig gets attacked -- line
noise and torn frames, a host process killed mid-episode, a spring that overheats.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

serial = pytest.importorskip("serial")

from neck_env.rig import protocol as P  # noqa: E402
from neck_env.rig.hardware_env import HardwareNeckEnv  # noqa: E402
from neck_env.rig.link import RigRefused  # noqa: E402

pytestmark = pytest.mark.hil


@pytest.fixture
def harness(closed_loop):
    """Factory: a paced harness running the firmware, with the simulator as the neck."""
    return lambda neck=True: closed_loop(7.0, seed=1, neck=neck)[0]


def _hostile_bytes(rng: random.Random) -> bytes:
    """Something that would switch relays on if any of it were acted on."""
    on = P.encode(P.SetRelays(0b111), rng.randrange(256))
    duty = P.encode(P.SetDuty((800, 800, 800)), rng.randrange(256))
    kind = rng.randrange(6)
    if kind == 0:  # line noise, sync bytes included
        return bytes(rng.choice((0xA5, 0x5A, rng.randrange(256))) for _ in range(rng.randrange(1, 40)))
    if kind == 1:  # a torn frame: the rest never comes
        return on[:rng.randrange(1, len(on) - 1)]
    if kind == 2:  # one bit flipped anywhere (CRC catches it)
        b = bytearray(duty)
        i = rng.randrange(2, len(b))
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b)
    if kind == 3:  # valid CRC but the complement byte does not match the mask
        return P.encode_frame(P.MsgType.SET_RELAYS, 7, bytes((0b111, 0x00)))
    if kind == 4:  # another protocol version
        return P.encode_frame(P.MsgType.SET_RELAYS, 7, P.SetRelays(7).payload(), version=2)
    return P.encode_frame(P.MsgType.SET_DUTY, 7, b"\xe8\x03" * 2)  # wrong length


def test_garbage_and_torn_frames_never_switch_a_relay_on(harness):
    """~4 s of hostile bytes on the firmware's UART while HardwareNeckEnv runs an episode with
    every relay commanded off: no relay ever switches on, the MCU never resets, and the env's
    own commands keep getting through (the parsers resynchronise)."""
    h = harness()
    env = HardwareNeckEnv(h.pty_path, action_mode="relay", episode_s=4.0, cooldown_s=0)
    rng = random.Random(5)
    env.reset(seed=0)
    bad0 = env.link.status().bad_frames
    sent = done = 0
    while not done:
        h.send_uart(_hostile_bytes(rng))
        sent += 1
        _, _, term, trunc, info = env.step(np.zeros(3, dtype=np.int8))
        done = term or trunc
        assert info["relays"] == (False, False, False)
    st = env.link.status()
    env.close()
    assert not any(ev.on for ev in h.relay_events), h.relay_events
    assert h.resets == [] and h.crash is None
    assert st.wdt_trips == 0 and not st.faults & P.Fault.WDT_RESET
    # most of the hostile chunks were counted as bad frames (line noise may hold no frame at all)
    print(f"\nhostile chunks {sent}, bad frames counted {st.bad_frames - bad0}")
    assert st.bad_frames - bad0 >= 0.4 * sent, (st.bad_frames - bad0, sent)


def test_a_killed_host_loses_its_relays_to_the_firmware_watchdog(harness, tmp_path):
    """The CLI runs a controller that holds every relay on; the host process is killed
    (SIGKILL: no cleanup code runs at all). The firmware's 250 ms heartbeat switches the
    relays off on its own; the recording is readable up to the kill."""
    h = harness(neck=False)
    cmd = [sys.executable, "-m", "neck_env.rig", "run", "--controller", "full_on",
           "--action-mode", "relay", "--port", h.pty_path, "--episode-s", "20",
           "--budget", "inf", "--no-cooldown", "--record", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        on = h.wait_relay(0, True, timeout=20.0)
        assert on is not None, proc.stderr.read1(4000) if proc.poll() is not None else "no relay"
        time.sleep(1.0)
        assert h.relay_pins() == (True, True, True)
        n = len(h.relay_events)
        proc.send_signal(signal.SIGKILL)
        t_kill = h.sim_time_us()
        proc.wait(5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    offs = [h.wait_relay(k, False, timeout=2.0, start=n) for k in range(3)]
    assert all(offs), h.relay_events[n:]
    # 250 ms watchdog after the last valid frame, which came at most one step (50 ms) before
    # the kill; plus a little scheduling slack
    latest = max(ev.t_us for ev in offs) - t_kill
    print(f"\nrelays off {latest / 1000:.0f} ms (simulated) after the host was killed")
    assert latest < 400_000, latest
    assert h.relay_pins() == (False, False, False)
    from neck_env.recording import read_recording

    rec = read_recording(sorted(tmp_path.glob("rec_*.csv"))[0])
    assert rec.duration_s > 0.8 and rec.i1.max() == pytest.approx(7.0)


def test_thermistor_cut_at_the_env_cutoff_in_firmware_and_host(harness):
    """With thermistors fitted the env configures the firmware's cut at its cutoff_C (160 C,
    the simulator's) instead of the firmware default of 110 C; a spring reading 160 C is cut by
    the firmware within milliseconds and held off by the host while it stays hot."""
    h = harness(neck=False)
    env = HardwareNeckEnv(h.pty_path, action_mode="relay", episode_s=10.0, cooldown_s=0,
                          thermistors=0b001)
    hello = env.link.request(P.Hello())
    assert P.ntc_adc_to_celsius(hello.therm_cut_adc) == pytest.approx(160.0, abs=2.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1, 0, 0]))
    h.set_adc(0, int(round(P.celsius_to_ntc_adc(130.0))))  # hot, above the old 110 C default
    for _ in range(4):
        _, _, _, _, info = env.step(np.array([1, 0, 0]))
    assert h.relay_pins()[0] and info["temperatures_C"][0] == pytest.approx(130.0, abs=1.5)
    n = len(h.relay_events)
    h.set_adc(0, hello.therm_cut_adc)  # 160 C
    off = h.wait_relay(0, False, timeout=1.0, start=n)
    assert off is not None
    for _ in range(6):
        _, _, _, _, info = env.step(np.array([1, 0, 0]))
        assert not h.relay_pins()[0]
    assert info["temperatures_C"][0] >= 158.0
    assert info["currents_A"][0] == 0.0
    h.set_adc(0, int(round(P.celsius_to_ntc_adc(140.0))))  # cooled below the release (150 C)
    for _ in range(6):
        _, _, _, _, info = env.step(np.array([1, 0, 0]))
    assert h.relay_pins()[0] and info["currents_A"][0] > 0
    env.close()
    assert h.relay_pins() == (False, False, False)


def test_imu_unplugged_mid_episode_stops_the_run_with_relays_off(harness):
    h = harness()
    env = HardwareNeckEnv(h.pty_path, action_mode="relay", episode_s=10.0, cooldown_s=0)
    env.reset(seed=0)
    for _ in range(4):
        env.step(np.array([0, 1, 0]))
    assert h.relay_pins()[1]
    h.set_imu_absent(True)
    # a read in flight fails (IMU_READ) or the next probe finds no device (IMU_MISSING)
    with pytest.raises(RigRefused, match=r"IMU fault.*IMU_(MISSING|READ)"):
        for _ in range(10):
            env.step(np.array([0, 1, 0]))
    time.sleep(0.05)
    assert h.relay_pins() == (False, False, False)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([0, 1, 0]))
    h.set_imu_absent(False)  # plugged back in: a new episode may start
    deadline = time.monotonic() + 3.0
    while True:  # the firmware re-probes the IMU about once a second
        try:
            env.reset(seed=1)
            break
        except RigRefused:
            assert time.monotonic() < deadline, "IMU not back after 3 s"
            time.sleep(0.2)
    env.close()
