"""``rig protocol``'s session (``neck_env.rig.session``) against the Python fake firmware: file
order is protocol order, the supply is asked for when it changes, an interrupted session
resumes (complete recordings skipped, a partial one kept aside and recorded again), a folder of
another protocol is refused. The real firmware and a real protocol: tests/hil."""

from __future__ import annotations

import json

import pytest

# against the clock (a fake firmware's watchdog and leases): run alone, as the hil tests are
pytestmark = pytest.mark.realtime

pytest.importorskip("serial")

from fake_firmware import FakeFirmware  # noqa: E402

from neck_env.experiments import Recording  # noqa: E402
from neck_env.recording import read_dataset  # noqa: E402
from neck_env.rig import cli  # noqa: E402
from neck_env.rig.link import RigLink  # noqa: E402
from neck_env.rig.session import run_protocol  # noqa: E402

# tiny relay pulses (a few tenths of a kelvin): the waits for rest are the 3 s settle only
RECS = [Recording("rec_01", "pulse", "m1 4 A", 4.0, 2.0, ((0.5, 0.7, (0,)),)),
        Recording("rec_02", "pulse", "m2 5 A", 5.0, 2.0, ((0.5, 0.7, (1,)),)),
        Recording("rec_03", "pulse", "m3 5 A", 5.0, 2.0, ((0.5, 0.6, (2,)),))]
PLAN = {"protocol": "test", "seed": 0}


@pytest.fixture
def fw():
    f = FakeFirmware()
    yield f
    f.close()


def _run(fw, folder, answers, recs=RECS, plan=PLAN, said=None, **kw):
    asked = []

    def ask(prompt):
        asked.append(prompt)
        a = answers.pop(0)
        if isinstance(a, BaseException):
            raise a
        return a

    with RigLink(fw.url) as link:
        res = run_protocol(link, folder, recs, plan, ask=ask, stream_hz=50,
                           say=(said.append if said is not None else lambda s: None), **kw)
    return res, asked


def test_session_records_in_order_asks_for_the_supply_and_resumes(fw, tmp_path):
    folder = tmp_path / "ds"
    # stop at the second supply prompt: rec_01 is done, rec_02 not started
    with pytest.raises(KeyboardInterrupt):
        _run(fw, folder, ["", KeyboardInterrupt()])
    assert fw.relays == 0
    assert sorted(p.name for p in folder.glob("*.csv")) == ["rec_01.csv"]
    # a recording interrupted half-way leaves a .part file; a truncated final file is not kept
    (folder / "rec_02.csv.part").write_text("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n")
    said: list[str] = []
    res, asked = _run(fw, folder, [""], said=said)
    assert res.skipped == ["rec_01"] and res.recorded == ["rec_02", "rec_03"]
    assert len(asked) == 1 and "5 A" in asked[0]  # rec_02 and rec_03 share a supply current
    assert [p.parent.name for p in res.moved_aside] == ["interrupted"]
    assert any("kept the interrupted recording" in s for s in said)
    ds = read_dataset(folder)
    assert [r.name for r in ds.recordings] == ["rec_01", "rec_02", "rec_03"]
    for r, rec in zip(ds.recordings, RECS):
        m = "i1 i2 i3".split()[int(rec.segments[0][2][0])]
        assert getattr(r, m).max() == pytest.approx(rec.supply_A)
        assert r.t[-1] >= rec.duration_s - 0.1
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["rest_tilt_deg"] == pytest.approx([0.0, 0.0], abs=0.1)  # the fake is upright
    assert [x["name"] for x in meta["protocol"]["recordings"]] == ["rec_01", "rec_02", "rec_03"]
    # all complete: nothing to do, nothing asked
    res, asked = _run(fw, folder, [])
    assert res.recorded == [] and res.skipped == ["rec_01", "rec_02", "rec_03"] and asked == []


def test_session_records_from_where_a_sticking_backbone_holds_the_neck(fw, tmp_path, monkeypatch):
    """After rec_01 the neck stays 1.5 deg off the session's rest reading with cold springs (a
    backbone with stiction): the session goes on from there instead of waiting out the rest
    timeout and stopping, says so, and writes which recordings started stuck, and where, to
    the session and to ``meta.json`` (``stuck_starts_tilt_deg``)."""
    import math
    from dataclasses import replace
    import neck_env.rig.hardware_env as H

    monkeypatch.setattr(H, "REST", replace(H.REST, stuck_s=2.0))
    a = math.radians(1.5)
    said: list[str] = []

    def say(line: str) -> None:
        said.append(line)
        if line.startswith("rec_01 done"):
            fw.accel = (0, round(8192 * math.sin(a)), round(8192 * math.cos(a)))

    folder = tmp_path / "ds"
    with RigLink(fw.url) as link:
        res = run_protocol(link, folder, RECS, PLAN, ask=lambda prompt: "", stream_hz=50, say=say)
    assert res.recorded == ["rec_01", "rec_02", "rec_03"] and res.rested_s < 30.0
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["rest_tilt_deg"] == pytest.approx([0.0, 0.0], abs=0.1)
    stuck = meta["stuck_starts_tilt_deg"]
    assert sorted(stuck) == ["rec_02", "rec_03"]
    for v in stuck.values():
        assert math.hypot(*v) == pytest.approx(1.5, abs=0.1)
    sess = json.loads((folder / "session.json").read_text())
    assert sess["done"]["rec_01"]["stuck_at_tilt_deg"] is None
    assert sum("backbone held the neck" in s for s in said) == 2, said


def test_session_refuses_another_protocol_and_foreign_recordings(fw, tmp_path):
    folder = tmp_path / "ds"
    _run(fw, folder, [""], recs=RECS[:1])
    with pytest.raises(ValueError, match="holds a session of another protocol"):
        _run(fw, folder, [], plan={"protocol": "test", "seed": 1}, recs=RECS[:1])
    other = tmp_path / "other"
    other.mkdir()
    (other / "rec_01.csv").write_text("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n")
    with pytest.raises(ValueError, match="that no protocol session made"):
        _run(fw, other, [""])


def test_session_checks_the_on_time_cap_and_needs_an_answer_or_yes(fw, tmp_path):
    long_on = Recording("rec_01", "pulse", "too long", 6.0, 14.0, ((1.0, 12.0, (0,)),))
    with pytest.raises(ValueError, match=r"on-time cap of 10 s or longer: rec_01 \(11 s\)"):
        _run(fw, tmp_path / "a", [], recs=[long_on])
    with pytest.raises(RuntimeError, match="pass --yes"):
        _run(fw, tmp_path / "b", [EOFError()])
    res, asked = _run(fw, tmp_path / "c", [], recs=RECS[:1], yes=True)
    assert res.recorded == ["rec_01"] and asked == []
    # a wire diameter in mm where metres are due is refused before anything runs
    with pytest.raises(ValueError, match=r"spring_wire_diameter_m must lie in .*0\.5 mm"):
        _run(fw, tmp_path / "d", [], recs=RECS[:1], yes=True, wire={"spring_wire_diameter_m": 0.5})
    assert not (tmp_path / "d").exists()


def test_protocol_cli_quick_run_and_supply_command(fw, tmp_path, capsys):
    supply = tmp_path / "supply_A"
    rc = cli.main(["protocol", "--port", fw.url, "--record", str(tmp_path / "ds"),
                   "--protocol", "paper", "--recordings", "1", "--duration", "8",
                   "--supply-cmd", f"echo {{amps}} > {supply}",
                   "--wire-diameter-mm", "0.5", "--wire-specific-heat", "322"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "protocol complete: 1 recorded now" in out.out
    ds = read_dataset(tmp_path / "ds")
    assert float(supply.read_text()) == ds.recordings[0].currents_A.max()
    # the wire as the diagnosis reads it, in SI units
    assert ds.meta["spring_wire_diameter_m"] == pytest.approx(0.0005)
    assert ds.meta["spring_specific_heat_J_kgK"] == 322


def test_session_holds_the_relay_plan_on_the_host_clock_through_stalled_steps(fw, tmp_path,
                                                                              monkeypatch):
    """A host that stalls (0.3 s before the first command, before the switch-on and inside the
    pulse) still switches each relay with the step that starts nearest the plan's edge, timed
    from the recording's first command; counted in steps, the stalls before the edge moved it
    0.6 s late and the one inside the pulse held the relay on 0.3 s longer."""
    import time

    from neck_env.rig import protocol as P
    from neck_env.rig.hardware_env import HardwareNeckEnv

    rec = Recording("rec_01", "pulse", "m1 4 A", 4.0, 2.5, ((0.8, 1.6, (0,)),))
    sent: list[tuple[int, float]] = []
    real_send = RigLink.send

    def logged_send(link, msg):
        if isinstance(msg, P.SetRelays) and steps:  # the episode's commands, not the rest wait's
            sent.append((msg.mask, time.monotonic()))
        return real_send(link, msg)

    real_step, steps = HardwareNeckEnv._step, []

    def stalling_step(env, currents_A):
        if len(steps) in (0, 5, 20):  # before the first command, at 0.25 s, at 1.0 s of plan
            time.sleep(0.3)
        steps.append(len(steps))
        return real_step(env, currents_A)

    monkeypatch.setattr(RigLink, "send", logged_send)
    monkeypatch.setattr(HardwareNeckEnv, "_step", stalling_step)
    res, _ = _run(fw, tmp_path / "ds", [""], recs=[rec])
    assert res.recorded == ["rec_01"]
    assert sent[0][0] == 0  # the plan's state at 0 s
    t0 = sent[0][1]
    k_on = next(k for k in range(len(sent)) if sent[k][0] == 0b001)
    k_off = next(k for k in range(k_on, len(sent)) if sent[k][0] == 0)
    assert all(mask == 0b001 for mask, _ in sent[k_on:k_off])
    half_step, slack = 0.025, 0.02  # slack: the host's time from its decision to the send
    for k, edge in ((k_on, 0.8), (k_off, 1.6)):
        assert sent[k][1] - t0 >= edge - half_step - slack, (k, sent[k][1] - t0)
        assert sent[k - 1][1] - t0 < edge - half_step + slack, (k, sent[k - 1][1] - t0)
    ds = read_dataset(tmp_path / "ds")
    # the recording is in the firmware's time: the stalls lengthen it, never shorten it
    assert ds.recordings[0].t[-1] >= rec.duration_s - 0.1
