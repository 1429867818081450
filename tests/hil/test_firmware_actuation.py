"""The simulated firmware actuation (``actuation="firmware"``, NeckTrack-v1) against the real
firmware ELF in simavr, and the shipped v1 policy on that rig through ``HardwareNeckEnv``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

serial = pytest.importorskip("serial")

import neck_env  # noqa: E402
from agents.controllers import make_controller  # noqa: E402
from agents.policy import DeployedPolicy  # noqa: E402
from neck_env.actuation import FIRMWARE, FirmwareLimits  # noqa: E402
from neck_env.envs import NeckTrackEnv  # noqa: E402
from neck_env.rig.hardware_env import HardwareNeckEnv  # noqa: E402

pytestmark = pytest.mark.hil

POLICY = Path(__file__).resolve().parents[2] / "agents" / "policies" / "ars_muscle_v1.zip"


def test_simulated_limits_are_what_the_firmware_reports(rig):
    _, _, link = rig()
    hi = link.hello
    assert FIRMWARE == FirmwareLimits(hi.duty_window_ms, hi.duty_max_permille, hi.ontime_cap_ms,
                                      hi.lockout_ms, hi.duty_bucket_cap_ms, hi.duty_bucket_drain)
    assert HardwareNeckEnv.ACTUATION == "firmware"


def test_duty_command_heats_as_the_simulated_firmware(rig):
    """A steady 8 A command: the rig delivers the capped duty of the supply, as the simulated
    firmware does (mean square current over whole 1 s windows = 0.8 I_s^2)."""
    _, _, link = rig()
    env = HardwareNeckEnv(link=link, episode_s=4.0, cooldown_s=0, energy_budget_J=float("inf"),
                          actuation="firmware")
    env.reset(seed=0)
    cur = []
    for _ in range(80):
        _, _, _, _, info = env.step(np.array([8.0, 0.0, 0.0], np.float32))
        cur.append(info["currents_A"][0])
    env.close()
    cur = np.array(cur[:60])  # three whole windows
    assert np.mean(cur ** 2) == pytest.approx(0.8 * 7.0 ** 2, rel=0.05)
    sim = NeckTrackEnv(episode_s=4.0, energy_budget_J=float("inf"), actuation="firmware")
    sim.reset(seed=0)
    sim_cur = np.array([sim.step(np.array([8.0, 0, 0], np.float32))[4]["currents_A"][0]
                        for _ in range(60)])
    assert np.mean(sim_cur ** 2) == pytest.approx(np.mean(cur ** 2), rel=0.05)
    # bursts of the full supply current, not a steady 6.26 A
    assert cur.max() == pytest.approx(7.0, rel=0.02) and cur.min() < 1.0


@pytest.mark.skipif(not POLICY.exists(), reason="no shipped v1 policy")
def test_shipped_v1_policy_holds_the_target_as_well_as_the_pid_on_the_rig(rig, capsys,
                                                                          one_target):
    """The issue's HIL criterion: over the last 4 s of a one-target episode the policy's error
    is within 0.5 deg of the PID's, both through HardwareNeckEnv on the firmware in simavr."""
    kw = dict(neck_env.V1_KWARGS, episode_s=14.0, targets=one_target)
    tails = {}
    for name in ("pid", "policy"):
        h, neck, link = rig()
        # remember=False: both emulated rigs may get the same pty name, and the thermal estimate
        # remembered per port would start the second episode with the first one's hot springs
        env = HardwareNeckEnv(link=link, cooldown_s=0, remember=False, **kw)
        if name == "pid":
            agent = make_controller("pid", kw)
        else:
            agent = DeployedPolicy.load(POLICY, env_kwargs=kw)
        agent.reset()
        obs, info = env.reset(seed=3)
        errs = []
        for _ in range(env.task.episode_steps):
            obs, _, _, _, info = env.step(agent.act(obs))
            errs.append(info["tracking_error_deg"])
        env.close()
        link.close()
        assert neck.error is None, neck.error
        # one real-time emulator at a time: a second one beside it misses replies when loaded
        neck.stop()
        h.close()
        tails[name] = float(np.mean(errs[-80:]))
        with capsys.disabled():
            print(f"\nHIL {name}: target {info['target_theta_deg']:.2f} deg, error over the last "
                  f"4 s {tails[name]:.2f} deg, energy {info['energy_J']:.0f} J")
    assert tails["policy"] <= tails["pid"] + 0.5, tails
