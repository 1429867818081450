"""Where the residual lies (``gap.localize``): co-activation, on constructed recordings."""

import numpy as np
import pytest

from neck_env.gap import localize


def _recording(segments, e_one: float, e_several: float, duration_s: float = 40.0,
               hz: float = 50.0) -> dict:
    """Commanded currents from (start, stop, muscle) segments; a tilt error of ``e_one`` deg
    where one muscle is warm and ``e_several`` where several are (zero at rest)."""
    t = np.arange(int(duration_s * hz)) / hz
    cmd = np.zeros((t.size, 3))
    for a, b, m in segments:
        cmd[(t >= a) & (t < b), m] = 6.0
    warm = localize.warm_muscles(t, cmd)
    e = np.where(warm >= 2, e_several, np.where(warm == 1, e_one, 0.0))
    return {"t": t, "cmd": cmd, "e_theta": e, "e_phi": e}


def test_warm_muscles_counts_the_muscles_on_or_recently_off():
    t = np.arange(0.0, 30.0, 0.5)
    cmd = np.zeros((t.size, 3))
    cmd[(t >= 2) & (t < 5), 0] = 6.0
    cmd[(t >= 8) & (t < 10), 1] = 6.0
    n = localize.warm_muscles(t, cmd)
    at = lambda s: int(n[np.searchsorted(t, s)])  # noqa: E731
    assert (at(1.0), at(3.0), at(6.0), at(9.0), at(12.0)) == (0, 1, 1, 2, 2)
    # with a 2 s cooling window muscle 1 is cold again by 9 s, and nothing is warm at 13 s
    n2 = localize.warm_muscles(t, cmd, cooling_s=2.0)
    assert (int(n2[np.searchsorted(t, 9.0)]), int(n2[np.searchsorted(t, 13.0)])) == (1, 0)


def test_a_misfit_of_several_muscles_together_is_located_there():
    pulse = [(2.0, 7.0, 0)]
    sequence = [(2.0, 5.0, 0), (5.0, 8.0, 1), (8.0, 11.0, 2)]
    recs = [_recording(pulse, 0.3, 0.0), _recording(sequence, 0.3, 0.9)]
    dec = localize.decompose(recs)
    pat = localize.pattern(dec, recs)
    assert pat["concentrated_in_activation"] == "several"
    assert pat["activation_rms_deg"]["one"] == pytest.approx(0.3)
    assert pat["activation_rms_deg"]["several"] == pytest.approx(0.9)
    # the same error everywhere: nothing stands out
    alike = [_recording(pulse, 0.3, 0.0), _recording(sequence, 0.3, 0.3)]
    assert localize.pattern(localize.decompose(alike), alike)["concentrated_in_activation"] \
        == "one and several alike"
    # single-muscle recordings only: nothing to compare
    only = [_recording(pulse, 0.3, 0.0), _recording([(2.0, 9.0, 2)], 0.5, 0.0)]
    pat = localize.pattern(localize.decompose(only), only)
    assert pat["concentrated_in_activation"] is None
    assert pat["activation_rms_deg"]["several"] is None


def test_a_noise_level_difference_does_not_stand_out():
    # four times the mean square but 0.04 deg more: within what the sensor leaves
    pulse = [(2.0, 7.0, 0)]
    sequence = [(2.0, 5.0, 0), (5.0, 8.0, 1)]
    recs = [_recording(pulse, 0.04, 0.0), _recording(sequence, 0.04, 0.08)]
    assert localize.pattern(localize.decompose(recs), recs)["concentrated_in_activation"] \
        == "one and several alike"


def test_the_console_reads_a_co_activation_misfit_as_structure_only_when_it_remains():
    from neck_env.gap.report import _activation_line
    several = {"concentrated_in_activation": "several",
               "activation_rms_deg": {"one": 0.58, "several": 1.02}}
    lines: list[str] = []
    _activation_line(lines, several, "    ")
    assert lines == ["    co-activation: several (tilt RMS with one muscle warm 0.58 deg, "
                     "several 1.02 deg)"]
    lines = []
    _activation_line(lines, several, "    remaining ", remaining=True)
    assert len(lines) == 5 and "fit one at a time but not together" in lines[1]
    lines = []
    _activation_line(lines, dict(several, concentrated_in_activation="one and several alike"),
                     "    remaining ", remaining=True)
    assert len(lines) == 1
    lines = []
    _activation_line(lines, {"concentrated_in_activation": None,
                             "activation_rms_deg": {"one": 0.3, "several": None}}, "    ")
    assert lines == []
