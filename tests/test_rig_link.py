"""The serial link and the hardware env against a Python fake firmware (no simavr, ~10 s).

The fake (``tests/fake_firmware.py``) is served as a pyserial ``socket://`` URL, so these
tests also exercise the URL path of :class:`neck_env.rig.link.RigLink`. The real firmware's
safety is tested in ``tests/hil``; here: error paths of the host side.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pytest

# against the clock (a fake firmware's watchdog and leases): run alone, as the hil tests are
pytestmark = pytest.mark.realtime

pytest.importorskip("serial")

from fake_firmware import FakeFirmware  # noqa: E402

import neck_env  # noqa: E402,F401  (registers NeckTrack-v0)
from neck_env.recording import read_dataset, read_recording  # noqa: E402
from neck_env.rig import protocol as P  # noqa: E402
from neck_env.rig.errors import (RigFirmwareReset, RigImuError, RigLinkLost,  # noqa: E402
                                 RigNotAtRest, RigRefused, RigTimeout)
from neck_env.rig.hardware_env import HardwareNeckEnv  # noqa: E402
from neck_env.rig.link import RigLink  # noqa: E402


@pytest.fixture
def fw():
    f = FakeFirmware()
    yield f
    f.close()


def _env(fw, **kw) -> HardwareNeckEnv:
    kw.setdefault("cooldown_s", 0)
    kw.setdefault("stream_hz", 50)
    return HardwareNeckEnv(fw.url, **kw)


# -- link --------------------------------------------------------------------------------------


def test_link_says_hello_and_matches_replies_by_seq(fw):
    with RigLink(fw.url) as link:
        assert link.hello.protocol_version == P.PROTOCOL_VERSION
        # garbage, a truncated frame and a foreign reply in front of the real ones
        fw.send_raw(b"\x00\xff\xa5\x5a\x01" + P.encode_frame(P.MsgType.ACK, 200, b"\x02\x00")[:-3])
        fw.send_raw(P.encode_frame(P.MsgType.ACK, 201, b"\x02\x00"))  # nobody asked
        ack = link.command(P.SetRelays(0b101))
        assert isinstance(ack, P.Ack) and ack.cmd_type == P.MsgType.SET_RELAYS
        assert fw.relays == 0b101
    # close() switched everything off
    assert fw.relays == 0 and isinstance(fw.received[-1], (P.Stream, P.Stop, P.SetRelays))


def test_link_refuses_another_protocol_version():
    with FakeFirmware(protocol_version=P.PROTOCOL_VERSION + 1) as fw:
        with pytest.raises(RigRefused, match=r"protocol 2, this host 1: flash the firmware"):
            RigLink(fw.url)


def test_link_without_answering_firmware_times_out_with_a_hint():
    with FakeFirmware(answer=False) as fw:
        t = time.monotonic()
        with pytest.raises(RigTimeout, match="no answer to HELLO within 0.6 s .*firmware flashed"):
            RigLink(fw.url, open_timeout=0.6)
        assert time.monotonic() - t < 2.0


def test_link_names_a_port_that_does_not_exist():
    with pytest.raises(RigLinkLost, match="cannot open /dev/does-not-exist"):
        RigLink("/dev/does-not-exist")
    with pytest.raises(ValueError, match="port must be"):
        RigLink("")


def test_link_vanished_port_is_a_clear_error_and_reconnect_recovers(fw):
    link = RigLink(fw.url)
    fw.vanish()
    time.sleep(0.1)
    with pytest.raises(RigLinkLost, match="serial link lost"):
        link.command(P.SetRelays(1))
    with pytest.raises(RigLinkLost):
        link.check()
    link.reconnect(open_timeout=2.0)  # the fake accepts a new connection (USB replugged)
    assert link.command(P.SetRelays(0)).cmd_type == P.MsgType.SET_RELAYS
    link.close()


def test_heartbeat_lease_bridges_a_slow_host_but_not_a_dead_one(fw):
    link = RigLink(fw.url)
    link.command(P.SetRelays(0b010))
    link.start_heartbeat(0.05)
    link.renew(0.6)
    time.sleep(0.45)  # longer than the firmware's 250 ms, within the lease
    assert fw.relays == 0b010 and fw.heartbeat_trips == 0
    time.sleep(0.6)  # the lease ran out: nobody feeds the watchdog any more
    assert fw.relays == 0 and fw.heartbeat_trips == 1
    n = sum(isinstance(m, P.Heartbeat) for m in fw.received)
    assert 4 <= n <= 14
    link.close()


# -- hardware env ------------------------------------------------------------------------------


def test_env_spaces_and_targets_are_those_of_necktrack(fw):
    for mode in ("current", "relay"):
        sim = gym.make("NeckTrack-v0", action_mode=mode, episode_s=30.0)
        env = _env(fw, action_mode=mode, episode_s=30.0)
        assert env.action_space == sim.action_space
        assert env.observation_space == sim.observation_space
        env.close()
    env = _env(fw, episode_s=30.0)
    sim = gym.make("NeckTrack-v0", episode_s=30.0)
    obs, _ = env.reset(seed=11)
    sobs, _ = sim.reset(seed=11)
    assert env.observation_space.contains(obs)
    np.testing.assert_allclose(obs[5:8], sobs[5:8], atol=1e-5)  # target and budget at t = 0
    # the same target trajectory: jump the step counters to 5 s and compare
    for _ in range(10):
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
        _, _, _, _, sinfo = sim.step(np.zeros(3, np.float32))
        assert info["target_theta_deg"] == pytest.approx(sinfo["target_theta_deg"], abs=1e-6)
    env.close()


def test_env_passes_the_gymnasium_checker(fw):
    """Every check of ``gymnasium.utils.env_checker.check_env`` that applies to a physical rig.
    Left out: ``check_step_determinism`` -- the same seed and action cannot give the same next
    observation on hardware (the springs are still warm from the previous step, the IMU is
    noisy); the sim env passes it."""
    from gymnasium.utils import env_checker as ec
    from gymnasium.utils.passive_env_checker import env_reset_passive_checker, env_step_passive_checker

    env = _env(fw, episode_s=2.0)
    for space in (env.action_space, env.observation_space):
        ec.check_space_limit(space, "space")
    ec.check_action_space(env.action_space)
    ec.check_observation_space(env.observation_space)
    ec.check_seed_deprecation(env)
    ec.check_reset_return_info_deprecation(env)
    ec.check_reset_return_type(env)
    ec.check_reset_seed_determinism(env)
    ec.check_reset_options(env)
    env_reset_passive_checker(env)
    env_step_passive_checker(env, env.action_space.sample())
    ec.check_returned_data_not_reused(env)
    env.close()


def test_env_invalid_action_turns_relays_off_and_names_the_problem(fw):
    env = _env(fw, action_mode="relay")
    env.reset(seed=0)
    env.step(np.array([1, 1, 0]))
    assert fw.relays == 0b011
    with pytest.raises(ValueError, match="relay action must be 0 or 1"):
        env.step(np.array([1, 2, 0]))
    time.sleep(0.05)
    assert fw.relays == 0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([1, 0, 0]))
    env.close()


def test_env_imu_fault_is_a_clear_error_with_relays_off():
    with FakeFirmware(imu_faults=int(P.Fault.IMU_MISSING)) as fw:
        with pytest.raises((RigImuError, RigRefused), match="IMU.*IMU_MISSING"):
            env = _env(fw)
            env.reset(seed=0)
        assert fw.relays == 0
    with FakeFirmware() as fw:
        env = _env(fw, action_mode="relay")
        env.reset(seed=0)
        env.step(np.array([0, 0, 1]))
        fw.imu_faults = int(P.Fault.IMU_READ)  # the IMU fails mid-episode
        with pytest.raises((RigImuError, RigRefused), match="IMU_READ"):
            for _ in range(5):
                env.step(np.array([0, 0, 1]))
        time.sleep(0.05)
        assert fw.relays == 0
        env.close()


def test_env_silent_firmware_times_out_with_relays_off(fw):
    env = _env(fw, action_mode="relay")
    env.reset(seed=0)
    env.step(np.array([1, 0, 0]))
    fw.silent = True
    with pytest.raises(RigTimeout, match="no reply to SetRelays|no telemetry"):
        for _ in range(20):
            env.step(np.array([1, 0, 0]))
    env.close()


def test_env_stalled_host_is_not_a_silent_link(fw):
    """A host that stalled (a garbage collection, a slow policy) finds its last telemetry old
    while fresh frames wait unread in the port: the reader drains them, the step goes on. A
    link that stays silent is still a timeout."""
    env = _env(fw, action_mode="relay")
    env.reset(seed=0)
    env.step(np.array([0, 0, 0]))  # relays off: a long stall below trips no heartbeat watchdog
    with env._lock:
        # the stall: the reader blocks on this lock, so the frames the firmware streams meanwhile
        # wait unread in the port (at 50 Hz, several in 0.2 s), and the last telemetry looks 1 s old
        env._last_host_t -= 1.0
        stale = env._last_host_t
        # held until frames wait: a starved fake-firmware thread once sent one in 0.2 s (CI, idle)
        time.sleep(0.2)
        end = time.monotonic() + 2.0
        while fw.telemetry_sent_since(stale + 1.0) < 2 and time.monotonic() < end:
            time.sleep(0.02)
    assert fw.telemetry_sent_since(stale + 1.0) >= 2  # the precondition: frames are waiting
    env._drain_after_stall()
    # a newer frame was read (how long the reader took is the machine's load, not behaviour)
    with env._lock:
        assert env._last_host_t > stale + 0.5
    env.step(np.array([1, 0, 0]))
    fw.silent = True
    with env._lock:
        env._last_host_t -= 1.0
    with pytest.raises(RigTimeout, match="no reply to SetRelays|no telemetry"):
        env.step(np.array([1, 0, 0]))
    env.close()


def test_env_late_s_counts_the_wait_for_telemetry(fw, monkeypatch):
    """A step that waited for telemetry after its deadline (the reader catching up after a
    stall) ended that much later, with its relay on all the while: ``late_s`` says so."""
    env = _env(fw, action_mode="relay")
    env.reset(seed=0)
    env.step(np.array([1, 0, 0]))
    drain = env._drain_after_stall
    monkeypatch.setattr(env, "_drain_after_stall", lambda: (time.sleep(0.2), drain()))
    _, _, _, _, info = env.step(np.array([1, 0, 0]))
    assert info["late_s"] >= 0.2
    env.close()


def test_env_mcu_restart_mid_episode_is_reported(fw):
    env = _env(fw, action_mode="relay")
    env.reset(seed=0)
    env.step(np.array([1, 0, 0]))
    fw.send_boot()
    fw.stream_hz = 50  # keep telemetry coming so only the BOOT can stop the episode
    with pytest.raises(RigFirmwareReset, match="restarted mid-episode"):
        for _ in range(5):
            env.step(np.array([1, 0, 0]))
    env.close()


def test_env_vanished_port_keeps_the_recording(fw, tmp_path):
    env = _env(fw, action_mode="relay", record_dir=tmp_path)
    env.reset(seed=0)
    for _ in range(20):  # 1 s
        env.step(np.array([0, 1, 0]))
    fw.vanish()
    with pytest.raises(RigLinkLost):
        for _ in range(20):
            env.step(np.array([0, 1, 0]))
    rec = read_recording(env.recordings[0])
    assert rec.n >= 40 and rec.duration_s >= 0.9  # 50 Hz for ~1 s, nothing lost
    assert rec.i2.max() == pytest.approx(7.0) and rec.i1.max() == 0.0
    ds = read_dataset(tmp_path)  # a dataset neck-gap can read
    assert len(ds) == 1 and ds.meta["sample_hz"] == 50
    # the port is back (USB replugged): reset reopens it and a new episode runs and records
    env.reset(seed=1)
    for _ in range(5):
        env.step(np.array([0, 1, 0]))
    assert fw.relays == 0b010
    env.close()
    assert fw.relays == 0 and len(read_dataset(tmp_path)) == 2


def test_env_energy_from_commanded_on_time_and_budget_cut(fw):
    env = _env(fw, action_mode="relay", energy_budget_J=30.0)
    env.reset(seed=0)
    R = env.estimate.resistance_ohm()[0]  # cold, martensite: ~constant over a few seconds
    n0, overrun_s, info = len(fw.relay_on_log), 0.0, {}
    for _ in range(40):  # 2 s
        t = time.monotonic()
        _, _, _, _, info = env.step(np.array([1, 0, 0]))
        # a step that took longer than dt (a stalled or loaded host) held its relay on that much
        # longer: the host cannot cut a relay while it is stalled, so that energy flows
        overrun_s += max(time.monotonic() - t - env.dt, 0.0)
        if info["budget_exhausted"]:
            break
    relay_s = _relay1_on_s(fw.relay_on_log[n0:], time.monotonic())  # the firmware's own log
    assert info["budget_exhausted"]
    # 7 A through ~R ohm: 49 R W. The charge is what the relay passed, trailing it by a
    # telemetry frame or two (20 ms each)
    assert info["energy_J"] / (49 * R) == pytest.approx(relay_s, abs=0.06)
    # the budget is spent after ~30 / (49 R) s and then cut: not a step early, and late only by
    # a frame's switching jitter and what a stalled host held on
    expect_s = 30.0 / (49 * R)
    assert expect_s - env.dt - 0.04 <= relay_s <= expect_s + 0.04 + overrun_s
    spent = info["energy_J"]
    for _ in range(3):
        _, _, _, _, info = env.step(np.array([1, 0, 0]))
    # relays stay off; in relay mode a last step that would overdraw is not taken at all, so
    # less than one step's energy may remain unspent, and nothing is spent after the cut but
    # the telemetry frame still in flight
    assert fw.relays == 0 and info["budget_exhausted"]
    assert 0.0 <= info["energy_left_J"] < 49 * R * env.dt
    assert info["energy_J"] <= spent + 49 * R * 0.02
    env.close()


def _relay1_on_s(log, t_end: float) -> float:
    """Seconds relay 1 was on in a firmware relay log [(monotonic time, mask), ...]."""
    on_s, since = 0.0, None
    for t, mask in log:
        if mask & 1 and since is None:
            since = t
        elif not mask & 1 and since is not None:
            on_s, since = on_s + t - since, None
    return on_s + (t_end - since if since is not None else 0.0)


def test_a_stalled_host_is_charged_what_its_relay_passed_until_the_heartbeat_cut_it(fw):
    """The host stalls 0.4 s with a relay on. The firmware's heartbeat (firmware/src/config.h,
    HEARTBEAT_TIMEOUT_MS = 250) switches it off within 0.25 s of the last command, so a stall
    overdraws a budget by at most that; the step after says how late it was (late_s), and the
    energy charged follows what the relay passed (the firmware's own log), stall included."""
    env = _env(fw, action_mode="relay", energy_budget_J=float("inf"))
    R = env.estimate.resistance_ohm()[0]
    charged_s, on_s, late_s = [], [], 0.0
    for stall_at in (None, 6):
        env.reset(seed=0)
        n0, info = len(fw.relay_on_log), {}
        for k in range(12):
            if k == stall_at:
                time.sleep(0.4)
            _, _, _, _, info = env.step(np.array([1, 0, 0]))
            if k == stall_at:
                late_s = info["late_s"]
        on_s.append(_relay1_on_s(fw.relay_on_log[n0:], time.monotonic()))
        charged_s.append(info["energy_J"] / (49 * R))  # 7 A through ~R ohm
    assert late_s >= 0.35 and fw.heartbeat_trips >= 1
    extra_on = on_s[1] - on_s[0]
    assert 0.1 < extra_on < fw.HEARTBEAT_S + env.dt  # on into the stall, then cut
    # each episode's charge trails its relay by a telemetry frame or two (20 ms each), up to
    # four on a loaded machine (at 0.05 s: 2 failures in 18 runs beside three busy processes)
    assert charged_s[1] - charged_s[0] == pytest.approx(extra_on, abs=0.08)
    env.close()


def test_env_temperature_estimate_keeps_cooling_between_episodes(fw):
    """Without thermistors the springs' temperatures come from the model on the commanded
    currents; between episodes (nobody stepping) the springs cool and so does the estimate."""
    env = _env(fw, action_mode="relay", energy_budget_J=float("inf"))
    env.reset(seed=0)
    for _ in range(40):  # 2 s at 7 A on muscle 1
        obs, _, _, _, info = env.step(np.array([1, 0, 0]))
    hot = obs[2]
    assert hot > 40.0 and obs[3] == pytest.approx(25.0, abs=0.5)  # only muscle 1 heated
    from neck_env.physics.plant import simulate, constants_from_params
    from neck_env.params import default_params

    time.sleep(1.5)
    obs, _ = env.reset(seed=1)
    # the model's own cooling over the ~1.5 s gap, within what a few steps of timing shift
    traj, _ = simulate(constants_from_params(default_params()),
                       np.concatenate([np.full((200, 1, 3), [7.0, 0, 0]), np.zeros((150, 1, 3))]),
                       0.01)
    drop = traj.T_C[199, 0, 0] - traj.T_C[-1, 0, 0]
    assert hot - obs[2] == pytest.approx(drop, rel=0.5), (hot, obs[2], drop)
    env.close()


def test_env_remembers_the_springs_across_processes_and_waits_for_rest(fw):
    """A second command on the same port starts from the springs the first one heated (saved
    with the wall-clock time, cooled over the gap), so it waits for rest -- and with
    ``require_rest`` refuses a neck that does not cool in time, naming the hot spring."""
    env = _env(fw, action_mode="relay", energy_budget_J=float("inf"))
    env.reset(seed=0)
    for _ in range(40):  # 2 s at 7 A on muscle 1
        obs, *_ = env.step(np.array([1, 0, 0]))
    hot = float(obs[2])
    env.close()
    assert hot > 40.0
    env2 = _env(fw, action_mode="relay", cooldown_s=1.0)  # a new process would do the same
    try:
        assert "last driven" in env2.memory_note
        assert env2.estimate.temperatures_C[0] > 35.0  # not the ambient a fresh estimate has
        with pytest.raises(RigNotAtRest, match=r"not at rest after 1 s: hottest spring \+\d"):
            env2.reset(seed=0, options={"require_rest": True})
        assert fw.relays == 0
    finally:
        env2.close()
    # without the memory a fresh estimate would start at ambient: the old behaviour
    env3 = _env(fw, action_mode="relay", remember=False)
    assert env3.estimate.temperatures_C[0] == pytest.approx(25.0)
    env3.close()


def test_env_waits_for_the_springs_to_cool_before_an_episode(fw):
    env = _env(fw, action_mode="relay", energy_budget_J=float("inf"))
    env.reset(seed=0)
    for _ in range(4):  # 0.2 s at 7 A: a few K above the rest margin, a short wait
        env.step(np.array([0, 1, 0]))
    env.close()
    env2 = _env(fw, action_mode="relay", cooldown_s=60.0)
    try:
        warm = float(env2.estimate.temperatures_C[1])
        assert warm > 28.0
        env2.reset(seed=0, options={"require_rest": True})
        r = env2.last_rest
        print(f"\nspring at {warm:.1f} C: at rest after {r.waited_s:.1f} s")
        # cooled below the margin, then held it for REST.settle_s
        assert r.at_rest and r.hottest_excess_K <= 3.0 and r.waited_s > 3.5
        assert env2.estimate.temperatures_C[1] <= 28.0
    finally:
        env2.close()


def test_env_waits_for_a_colder_start_but_not_forever_on_a_wrong_ambient(fw, monkeypatch):
    """``start_within_K`` (the ``rig`` protocol's reference and long tails start within 1 K of
    ambient): thermistors steady at 1.8 K over the ambient the host was given are at rest at
    once for REST's 3 K, and for the colder start once they have stopped cooling
    (``plateau_s``) -- a wrong ambient costs a short wait, not ``RigNotAtRest``."""
    from dataclasses import replace
    import neck_env.rig.hardware_env as H

    monkeypatch.setattr(H, "REST", replace(H.REST, plateau_s=4.0))
    fw.therm_adc = [491, 491, 491]  # 26.8 C
    env = _env(fw, action_mode="relay", thermistors=0b111, ambient_C=25.0, cooldown_s=30.0,
               remember=False)
    try:
        env.reset(seed=0, options={"require_rest": True})
        loose = env.last_rest
        env.reset(seed=0, options={"require_rest": True, "start_within_K": 1.0})
        tight = env.last_rest
        assert loose.at_rest and tight.at_rest and tight.temperature_source == "thermistor"
        assert tight.hottest_excess_K == pytest.approx(1.8, abs=0.05)
        assert loose.waited_s < 4.0 + H.REST.settle_s - 0.5 <= tight.waited_s < 15.0, (loose, tight)
        with pytest.raises(ValueError, match="start_within_K must be a positive"):
            env.reset(seed=0, options={"start_within_K": 0})
    finally:
        env.close()


def test_env_starts_from_where_a_sticking_backbone_holds_the_neck(monkeypatch):
    """Springs cold, the neck 1.5 deg off the session's rest reading and not moving (a backbone
    with stiction holds it: the plant with the catalogue's 0.02 N m of friction stops 0.8 deg
    off after a 7 A pulse, at 0.05 N m 1.9 deg): no wait brings it back, so ``wait_for_rest``
    takes it as at rest there after ``stuck_s`` instead of waiting out ``cooldown_s`` -- the
    rig's protocol would otherwise stop with ``RigNotAtRest`` after 15 min. Off the rest
    reading and moving, or warm, is not stuck."""
    import math
    from dataclasses import replace
    import neck_env.rig.hardware_env as H

    monkeypatch.setattr(H, "REST", replace(H.REST, stuck_s=2.0))
    tilt = math.radians(1.5)
    said: list[str] = []
    with FakeFirmware(accel=(round(8192 * math.sin(tilt)), 0, round(8192 * math.cos(tilt)))) as fw:
        env = _env(fw, action_mode="relay", cooldown_s=30.0, remember=False, say=said.append)
        try:
            t = time.monotonic()
            env.reset(seed=0, options={"rest_tilt_deg": (0.0, 0.0), "require_rest": True})
            r = env.last_rest
            assert r.at_rest and r.stuck, r
            assert 2.0 <= r.waited_s < 10.0 and time.monotonic() - t < 15.0
            assert r.tilt_off_deg == pytest.approx(1.5, abs=0.1)
            assert math.hypot(*r.rest_tilt_deg) == pytest.approx(1.5, abs=0.1)
            assert any("backbone holds it there" in m and "nudge" in m for m in said), said
            # the tilt given as the rest reading: at rest as before, not stuck
            env.reset(seed=0, options={"rest_tilt_deg": r.rest_tilt_deg, "require_rest": True})
            assert env.last_rest.at_rest and not env.last_rest.stuck
        finally:
            env.close()
    # a neck off its rest reading that keeps moving is not stuck: it is waited for
    with FakeFirmware(accel=(round(8192 * math.sin(tilt)), 0, round(8192 * math.cos(tilt)))) as fw:
        env = _env(fw, action_mode="relay", cooldown_s=4.0, remember=False)
        stop = False

        def sway() -> None:  # +-1.5 deg about x, a full swing every 1.2 s
            k = 0
            while not stop:
                a = tilt * (1 if (k // 6) % 2 == 0 else -1)
                fw.accel = (round(8192 * math.sin(a)), 0, round(8192 * math.cos(a)))
                k += 1
                time.sleep(0.1)

        import threading
        th = threading.Thread(target=sway, daemon=True)
        th.start()
        try:
            with pytest.raises(RigNotAtRest, match="not at rest after 4 s"):
                env.reset(seed=0, options={"rest_tilt_deg": (0.0, 0.0), "require_rest": True})
        finally:
            stop = True
            th.join()
            env.close()


@pytest.mark.parametrize("mask", [0b101, 0b111])
def test_env_records_the_fitted_thermistors_and_a_sensor_that_drops_out(fw, tmp_path, mask):
    """T1..T3 hold only thermistor readings, one column per fitted thermistor (the model's
    estimate goes to Tk_est). A thermistor whose wire comes loose mid-episode (reads open: the
    firmware holds its muscle off) leaves empty cells, not an aborted recording, and the
    diagnosis reads the folder with the readings it has."""
    env = _env(fw, action_mode="relay", thermistors=mask, record_dir=tmp_path)
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([1, 0, 0]))
    fw.therm_adc = [512, 512, 1023]  # muscle 3's sensor reads open
    for _ in range(10):
        env.step(np.array([1, 0, 0]))
    env.close()
    header = env.recordings[0].read_text().splitlines()[0].split(",")
    want = ["T1", "T2", "T3"] if mask == 0b111 else ["T1", "T3"]
    assert [c for c in header if c.startswith("T") and not c.endswith("_est")] == want
    rec = read_recording(env.recordings[0])
    assert rec.n >= 18
    T = rec.temperatures_C
    assert np.isfinite(T[:, 0]).all() and np.isnan(T[-5:, 2]).all() and np.isfinite(T[:5, 2]).all()
    assert np.isnan(T[:, 1]).all() != (mask == 0b111)
    assert read_dataset(tmp_path).has_temperatures
