"""The emulated rig's neck (``neck_env.rig.sim_neck.SimulatedNeck``) carries the catalogue's
effects: checked against a stand-in harness (relay events and a clock), without simavr."""

from __future__ import annotations

import numpy as np
import pytest

from neck_env.physics import layout as L
from neck_env.rig.simavr import RelayEvent
from neck_env.rig.sim_neck import SimulatedNeck


class ClockHarness:
    """What SimulatedNeck uses of SimavrHarness: a simulated clock, relay events, sensors (an
    IMU sample queue served by time, as the harness's IMU_AT)."""

    def __init__(self, events):
        self.t_us = 0
        self.relay_events = events
        self._imu = None
        self.queue = []

    def sim_time_us(self):
        return self.t_us

    def set_imu(self, *raw):
        self._imu = raw

    def imu_at(self, samples):
        t0 = samples[0][0]
        self.queue = [s for s in self.queue if s[0] < t0] + [tuple(s) for s in samples]

    @property
    def imu(self):
        due = [s for s in self.queue if s[0] <= self.t_us]
        return due[-1][1:] if due else self._imu

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


def test_a_relay_edge_learnt_late_rewinds_the_plant_to_it():
    """The plant runs ahead of the emulator's clock; a relay edge that happened after its last
    update (its thread scheduled 100 ms late, the plant already past the edge) sends it back to
    the edge, and the result is the trajectory -- and the IMU sample due now -- it would have
    had knowing the edge on time."""
    edge = RelayEvent(1_150_000, 0, True)
    ref_h, late_h = ClockHarness([edge]), ClockHarness([])
    ref = SimulatedNeck(ref_h, supply_current_A=7.0, sensors=None)
    late = SimulatedNeck(late_h, supply_current_A=7.0, sensors=None)
    ref.update()
    late.update()
    for k in range(1, 41):  # 4 s, one update per 100 ms
        ref_h.t_us = late_h.t_us = k * 100_000
        if k == 12:  # the edge at 1.15 s, learnt at 1.2 s: the plant had run to 1.35 s
            assert late.t_us >= 1_350_000
            late_h.relay_events = [edge]
        ref.update()
        late.update()
    assert late.rewinds == 1 and ref.rewinds == 0
    np.testing.assert_allclose([e[1] for e in late.log], [e[1] for e in ref.log], atol=1e-12)
    assert late.log[-1][3] == (True, False, False)
    assert late_h.imu == ref_h.imu and late.theta_deg == ref.theta_deg > 3.0
    np.testing.assert_allclose(late.temperatures_C, ref.temperatures_C)
