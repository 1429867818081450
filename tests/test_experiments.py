"""The recording protocol shared by the synthetic generators, the rig and the docs."""

import numpy as np
import pytest

from neck_env.experiments import PROTOCOLS, REST, diagnosis_protocol, protocol_schedule

FIRMWARE_ONTIME_CAP_S = 10.0  # firmware/src/config.h ONTIME_CAP_MS


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_protocol_is_seeded_and_runs_on_the_rig(protocol):
    a = diagnosis_protocol(4, protocol)
    b = diagnosis_protocol(4, protocol)
    assert [r.description for r in a] == [r.description for r in b]
    assert len({r.name for r in a}) == len(a)  # names are unique: the rig resumes by them
    for rec in a:
        assert 4.0 <= rec.supply_A <= 8.0
        assert rec.longest_on_s < FIRMWARE_ONTIME_CAP_S
        # every recording starts at rest and ends with a cooling tail (drawn: another lab's
        # timing, from 0.5 s and with at least 8 s of cooling)
        first_on, tail = (0.5, 8.0) if protocol == "drawn" else (2.0, 10.0)
        assert all(t_on >= first_on - 1e-9 for t_on, _, _ in rec.segments)
        assert rec.duration_s - max(t_off for _, t_off, _ in rec.segments) >= tail - 1e-9


def test_mixed_protocol_covers_muscles_currents_and_kinds():
    recs = diagnosis_protocol(0, "mixed")
    assert len(recs) == 15
    kinds = [r.kind for r in recs]
    assert kinds.count("pulse") == 9 and kinds.count("sequence") == 3 and kinds.count("cycles") == 3
    pulses = [r for r in recs if r.kind == "pulse"]
    assert {r.segments[0][2][0] for r in pulses} == {0, 1, 2}
    amps = sorted(r.supply_A for r in pulses)
    assert amps[0] == 4.0 and amps[-1] == 8.0


def test_rig_protocol_adds_long_cooling_tails():
    recs = diagnosis_protocol(0, "rig")
    assert [r.kind for r in recs[-2:]] == ["long_cool", "long_cool"]
    assert all(r.duration_s >= 60.0 for r in recs[-2:])


def test_drawn_protocol_varies_the_timing_within_the_rig_limits():
    recs = [r for seed in range(20) for r in diagnosis_protocol(seed, "drawn")]
    starts = [r.segments[0][0] for r in recs]
    pulses = [r for r in recs if r.kind == "pulse"]
    ons = [r.segments[0][1] - r.segments[0][0] for r in pulses]
    assert min(starts) < 1.0 and max(starts) > 3.5  # not the mixed protocol's 2 s
    assert min(ons) < 3.5 and max(ons) > 8.0  # not its 5 s
    assert len({r.supply_A for r in pulses}) > 20  # levels anywhere in 4-8 A, not a fixed set
    assert {r.kind for r in recs} == {"pulse", "sequence", "cycles"}
    # the same mixed protocol as before for the same seed (the drawn one has its own branch)
    assert [r.description for r in diagnosis_protocol(0, "mixed")][0] == "pulse m3 8 A 5 s"
    short = diagnosis_protocol(1, "drawn", n_recordings=6, duration_s=12.0)
    assert all(r.duration_s - max(b for _, b, _ in r.segments) >= 8.0 - 1e-9 for r in short)
    with pytest.raises(ValueError, match="at least 11 s"):
        diagnosis_protocol(0, "drawn", duration_s=10.0)


def test_schedule_matches_relays_and_on_time():
    rec = diagnosis_protocol(2, "mixed")[0]
    t = np.arange(int(rec.duration_s * 50) + 1) / 50
    cur = rec.currents(t)
    for k in range(0, len(t), 37):
        on = rec.relays_at(t[k])
        assert tuple(cur[k] > 0) == on
    assert np.allclose((cur > 0).sum(0) / 50, rec.on_time_s, atol=0.05)
    (desc, sched), = protocol_schedule(np.random.default_rng(2), "mixed", 1, 30.0, 50.0)[:1]
    assert sched.shape == (1501, 3)


def test_bad_protocol_arguments_are_named():
    with pytest.raises(ValueError, match="unknown protocol 'bogus'"):
        diagnosis_protocol(0, "bogus")
    with pytest.raises(ValueError, match="longer than"):
        diagnosis_protocol(0, "mixed", duration_s=5.0)
    assert REST.tilt_deg > 0 and REST.temperature_K > 0
