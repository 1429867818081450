"""Closed-loop hardware in the loop: ``HardwareNeckEnv`` -- the code a user runs on the rig --
on the real firmware ELF in simavr, with the simulator playing the neck
(``neck_env.rig.sim_neck.SimulatedNeck``: relay pins -> currents -> plant -> IMU registers)."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

serial = pytest.importorskip("serial")

from agents.controllers import make_controller  # noqa: E402
from agents.policy import DeployedPolicy  # noqa: E402
from neck_env.params import default_params  # noqa: E402
from neck_env.physics.plant import constants_from_params, simulate  # noqa: E402
from neck_env.recording import read_recording  # noqa: E402
from neck_env.rig.hardware_env import HardwareNeckEnv  # noqa: E402
from neck_env.rig.link import RigError, RigRefused  # noqa: E402

pytestmark = pytest.mark.hil

POLICY = Path(__file__).resolve().parents[2] / "agents" / "policies" / "ppo_necktrack.zip"


def _episode(env, act, seed):
    obs, info = env.reset(seed=seed)
    errs, done = [], False
    while not done:
        obs, r, term, trunc, info = env.step(act(obs))
        errs.append(info["tracking_error_deg"])
        done = term or trunc
    return np.array(errs), info


@pytest.mark.parametrize("agent", ["pid", "ppo"])
def test_closed_loop_episode_moves_head_to_target(rig, tmp_path, agent, one_target):
    h, neck, link = rig(7.0)
    env = HardwareNeckEnv(link=link, episode_s=14.0, cooldown_s=0, targets=one_target,
                          record_dir=tmp_path)
    if agent == "pid":
        ctrl = make_controller("pid", {"episode_s": 14.0})
        ctrl.reset(0)
        act = ctrl.act
    else:
        pol = DeployedPolicy.load(POLICY)
        pol.reset()
        act = lambda obs: np.clip(pol.act(obs), 0.0, 8.0).astype(np.float32)
    errs, info = _episode(env, act, seed=3)
    env.close()
    assert neck.error is None, neck.error
    target = info["target_theta_deg"]
    assert target >= 12.0
    # doing nothing scores the target tilt itself; over the last 4 s the head is much closer
    tail = errs[-80:].mean()
    print(f"\n{agent}: target {target:.2f} deg, tail error {tail:.2f} deg, neck theta "
          f"{neck.theta_deg:.2f} deg, energy {info['energy_J']:.0f} J")
    assert tail < 0.6 * target, f"{agent}: tail error {tail:.2f} deg vs target {target:.2f} deg"
    assert neck.theta_deg > 0.4 * target  # the simulated neck really moved
    assert 0 < info["energy_J"] <= 1500
    rec = read_recording(env.recordings[0])
    assert rec.n > 0.9 * 14.0 * 100  # telemetry rate rows
    assert rec.currents_A.max() == pytest.approx(7.0)
    assert abs(rec.theta_deg[-50:].mean() - neck.theta_deg) < 1.5


def test_pulse_reproduces_simulated_theta(rig, tmp_path):
    """The paper's step experiment through the whole chain: relay on for 5 s at 6 A, then
    cooling; the measured theta(t) matches the simulator driven by the recorded commands."""
    h, neck, link = rig(6.0)
    env = HardwareNeckEnv(link=link, action_mode="relay", supply_current_A=6.0,
                          energy_budget_J=float("inf"), episode_s=10.0, cooldown_s=0,
                          record_dir=tmp_path)
    env.reset(seed=0)
    for k in range(int(10.0 / env.dt)):
        env.step(np.array([1 if k * env.dt < 5.0 else 0, 0, 0]))
    env.close()
    rec = read_recording(env.recordings[0])
    dt = 0.01
    t = rec.t
    grid = np.arange(0.0, t[-1], dt)
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, rec.n - 1)
    cur = rec.currents_A[idx][:, None, :]
    traj, _ = simulate(constants_from_params(default_params()), cur, dt)
    sim_theta = np.interp(t, grid + dt, traj.theta_deg[:, 0])
    on_s = (rec.i1 > 0).sum() / 100.0
    assert 4.7 < on_s < 5.3  # the relay was on for the commanded 5 s
    err = rec.theta_deg - sim_theta
    print(f"\npulse 6 A x 5 s: peak measured {rec.theta_deg.max():.2f} deg, simulated "
          f"{sim_theta.max():.2f} deg, RMS difference {np.sqrt(np.mean(err ** 2)):.3f} deg")
    # IMU noise and bias (SensorParams: 4 mg noise, 8 mg bias ~ 0.5 deg) bound the agreement
    assert np.sqrt(np.mean(err ** 2)) < 1.0, np.sqrt(np.mean(err ** 2))
    assert abs(rec.theta_deg.max() - sim_theta.max()) < 1.0
    assert sim_theta.max() > 8.0  # a 6 A pulse bends the neck (Table 1: 11.3 deg)
    phi = rec.phi_deg[rec.theta_deg > 5.0]
    assert np.all(np.abs((phi - 180.0 + 180.0) % 360.0 - 180.0) < 5.0)  # toward muscle 1


def test_host_silence_switches_relays_off(rig):
    h, neck, link = rig(7.0)
    sent = []  # when the host wrote each frame (a step's command or a lease heartbeat)
    send = link.send

    def timed_send(msg):
        seq = send(msg)
        sent.append(time.monotonic())
        return seq

    link.send = timed_send
    env = HardwareNeckEnv(link=link, action_mode="relay", episode_s=5.0, cooldown_s=0)
    env.reset(seed=0)
    for _ in range(4):
        env.step(np.array([1, 1, 0]))
    assert any(h.relay_pins())
    t_last = time.monotonic()
    # the host stops acting (a hung policy): no step, and its heartbeat lease runs out
    while any(h.relay_pins()):
        assert time.monotonic() - t_last < 1.0, "relays still on 1 s after the host went silent"
        time.sleep(0.01)
    # the firmware's 250 ms watchdog after the host's last frame, not the host: timed from
    # that frame (a step returns a control period after its command, so timing from the
    # step's return would leave the watchdog up to that much less)
    t_off = time.monotonic()
    print(f"\nrelays off {1000 * (t_off - sent[-1]):.0f} ms after the host's last frame "
          f"({1000 * (t_off - t_last):.0f} ms after its last step returned)")
    assert t_off - sent[-1] > 0.2
    env.close()


def test_ctrl_c_during_a_step_switches_relays_off(rig, tmp_path):
    h, neck, link = rig(7.0)
    env = HardwareNeckEnv(link=link, action_mode="relay", episode_s=5.0, cooldown_s=0,
                          record_dir=tmp_path)
    env.reset(seed=0)
    env.step(np.array([1, 0, 1]))
    assert h.relay_pins() == (True, False, True)
    main = threading.main_thread().ident
    # a shell starts background jobs with SIGINT ignored: make Ctrl-C raise here regardless
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Timer(0.02, lambda: signal.pthread_kill(main, signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt):
            for _ in range(20):
                env.step(np.array([1, 0, 1]))
    finally:
        signal.signal(signal.SIGINT, old)
    time.sleep(0.05)
    assert h.relay_pins() == (False, False, False)
    rec = read_recording(env.recordings[0])  # flushed and readable
    assert rec.n > 0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([1, 0, 0]))
    env.close()


def test_absent_imu_is_a_clear_error(rig):
    h, neck, link = rig(7.0, imu_absent=True)
    with pytest.raises(RigRefused, match="IMU"):
        env = HardwareNeckEnv(link=link, cooldown_s=0)
        env.reset(seed=0)
    assert h.relay_pins() == (False, False, False)


def test_vanished_port_mid_episode(rig, tmp_path):
    h, neck, link = rig(7.0)
    env = HardwareNeckEnv(link=link, action_mode="relay", episode_s=10.0, cooldown_s=0,
                          record_dir=tmp_path)
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([0, 1, 0]))
    neck.stop()
    h.close()  # the UNO is unplugged: the pty goes away
    with pytest.raises(RigError):
        for _ in range(20):
            env.step(np.array([0, 1, 0]))
    rec = read_recording(env.recordings[0])
    assert rec.n >= 90  # ~1 s of telemetry before the port vanished, intact
    assert rec.i2.max() == pytest.approx(7.0)
    env.close()  # closing after the loss is safe
