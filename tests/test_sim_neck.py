"""The emulated rig's neck (``neck_env.rig.sim_neck.SimulatedNeck``) carries the catalogue's
effects: checked against a stand-in harness (relay events and a clock), without simavr."""

from __future__ import annotations

import numpy as np
import pytest

from neck_env.physics import layout as L
from neck_env.rig.simavr import RelayEvent
from neck_env.rig.sim_neck import SimulatedNeck


class ClockHarness:
    """What SimulatedNeck uses of SimavrHarness: a simulated clock, relay events, sensors."""

    def __init__(self, events):
        self.t_us = 0
        self.relay_events = events
        self.imu = None

    def sim_time_us(self):
        return self.t_us

    def set_imu(self, *raw):
        self.imu = raw

    def set_adc(self, ch, v):
        pass


def _heat_onset_s(effects, t_on_s=1.0):
    h = ClockHarness([RelayEvent(int(t_on_s * 1e6), 0, True)])
    neck = SimulatedNeck(h, supply_current_A=7.0, sensors=None, effects=effects)
    neck.update()
    onset = None
    for k in range(1, 301):  # 3 s in 10 ms ticks
        h.t_us = k * 10_000
        neck.update()
        if onset is None and neck.temperatures_C[0] > 25.05:
            onset = k * 0.01
    return onset, neck


def test_actuation_delay_applies_relay_edges_late():
    plain, _ = _heat_onset_s({})
    late, neck = _heat_onset_s({"actuation_delay": {"delay_s": 0.4}})
    assert plain == pytest.approx(1.01, abs=0.02)
    assert late - plain == pytest.approx(0.4, abs=0.02)
    assert neck.delay_us == 400_000


def test_imu_misalignment_and_plant_effects_reach_the_neck():
    _, neck = _heat_onset_s({"imu_misalignment": {"yaw_deg": 12.0, "tilt_deg": 3.0},
                             "head_payload": {"mass_kg": 0.3}})
    assert neck.consts[0, L.PAYLOAD_MG] == pytest.approx(0.3 * 9.81)
    # upright neck (t < 1 s the relay is off): a 3 deg tilted mount reads ~sin(3 deg) g sideways
    h = ClockHarness([])
    upright = SimulatedNeck(h, sensors=None, effects={"imu_misalignment": {"yaw_deg": 0.0,
                                                                           "tilt_deg": 3.0}})
    upright.update()
    ax, ay, az = (v / 8192.0 for v in h.imu[:3])
    assert np.degrees(np.arctan2(np.hypot(ax, ay), az)) == pytest.approx(3.0, abs=0.05)


def test_gyro_bias_drift_grows_with_the_emulators_time():
    rate = 0.015  # deg/s per s
    h = ClockHarness([])
    neck = SimulatedNeck(h, sensors=None, effects={"gyro_bias_drift": {"drift_dps_per_s": rate}})
    still = SimulatedNeck(ClockHarness([]), sensors=None)
    neck.update()
    assert h.imu[3] == h.imu[4] == 0  # upright, at rest, no drift yet
    for k in range(1, 2001):  # 20 s
        h.t_us = k * 10_000
        neck.update()
    lsb = 65.5  # gyro LSB per deg/s
    assert h.imu[3] / lsb == pytest.approx(rate * 20.0, abs=1 / lsb)
    assert h.imu[4] / lsb == pytest.approx(rate * 20.0, abs=1 / lsb)
    assert h.imu[5] == 0 and still.gyro_drift_dps_per_s == 0.0
