"""``neck-gap`` finds recordings that do not start at rest (``neck_env.gap.rest``), says which
and by how much, and keeps them out of the diagnosis instead of inflating the gap."""

from __future__ import annotations

import json

import numpy as np
import pytest

from neck_env.experiments import REST
from neck_env.gap.cli import main as gap_main
from neck_env.gap.rest import SLACK, not_at_rest, without
from neck_env.gap.synthetic import generate
from neck_env.recording import read_dataset, read_recording, write_recording


def _bend_start(path, theta0_deg: float = 8.0, phi_deg: float = 60.0, warm_K: float = 0.0,
                lead_s: float = 1.0) -> None:
    """Prepend ``lead_s`` of a neck still bent (theta falling from ``theta0_deg`` toward the
    recording's own start, as a neck cooling from the previous recording does) to a recording."""
    r = read_recording(path)
    dt = float(r.t[1] - r.t[0])
    n = int(round(lead_s / dt))
    t = np.concatenate([np.arange(n) * dt, r.t + n * dt])
    th_lead = r.theta_deg[0] + (theta0_deg - r.theta_deg[0]) * np.exp(-np.arange(n) * dt / 3.0)
    cols = {"t": t, "i1": np.r_[np.zeros(n), r.i1], "i2": np.r_[np.zeros(n), r.i2],
            "i3": np.r_[np.zeros(n), r.i3], "theta_deg": np.r_[th_lead, r.theta_deg],
            "phi_deg": np.r_[np.full(n, phi_deg), r.phi_deg]}
    if r.temperatures_C is not None:
        T = r.temperatures_C
        lead = np.repeat(T[:1] + warm_K, n, axis=0)
        for k in range(3):
            cols[f"T{k + 1}"] = np.r_[lead[:, k], T[:, k]]
    write_recording(path, cols)


def test_bent_and_warm_starts_are_found_and_measured(tmp_path):
    ds_dir = tmp_path / "ds"
    generate(ds_dir, [], seed=4, n_recordings=6, duration_s=12.0, temperatures=True)
    assert not_at_rest(read_dataset(ds_dir)) == []  # the generator starts every one at rest
    _bend_start(ds_dir / "rec_03.csv", theta0_deg=8.0)
    _bend_start(ds_dir / "rec_05.csv", theta0_deg=0.0, warm_K=15.0)
    ds = read_dataset(ds_dir)
    found = {b["recording"]: b for b in not_at_rest(ds)}
    assert set(found) == {"rec_03", "rec_05"}
    assert found["rec_03"]["tilt_off_deg"] == pytest.approx(7.0, abs=1.5)  # mean over 0.5 s
    assert "deg from the rest tilt" in found["rec_03"]["why"]
    assert found["rec_05"]["temperature_excess_K"] == pytest.approx(15.0, abs=2.0)  # meta ambient +- noise
    assert "K above ambient" in found["rec_05"]["why"]
    assert [r.name for r in without(ds, ["rec_03", "rec_05"])] == ["rec_01", "rec_02", "rec_04",
                                                                      "rec_06"]
    # a start within the rig's own criterion (it waits for REST) is not flagged
    _bend_start(ds_dir / "rec_02.csv", theta0_deg=0.8 * REST.tilt_deg, lead_s=0.6)
    assert "rec_02" not in {b["recording"] for b in not_at_rest(read_dataset(ds_dir))}
    assert SLACK * REST.tilt_deg < 2.0


def _shift_rest(path, dx_deg: float) -> None:
    """Move a recording's whole tilt reading by ``dx_deg`` along x: where its rest reads."""
    r = read_recording(path)
    ph = np.radians(r.phi_deg)
    x, y = r.theta_deg * np.cos(ph) + dx_deg, r.theta_deg * np.sin(ph)
    cols = {"t": r.t, "i1": r.i1, "i2": r.i2, "i3": r.i3, "theta_deg": np.hypot(x, y),
            "phi_deg": np.degrees(np.arctan2(y, x)) % 360.0}
    write_recording(path, cols)


def test_a_slowly_moving_rest_is_not_a_start_away_from_rest(tmp_path):
    """Springs taking a permanent set, or an IMU bias drifting, move the rest reading through
    the session (here 3 deg from first to last of 8 recordings, 2.5 x the flagging threshold
    end to end): no recording is flagged for that; a bent start on top of it still is."""
    ds_dir = tmp_path / "ds"
    generate(ds_dir, [], seed=5, n_recordings=8, duration_s=10.0, temperatures=False)
    for k in range(8):
        _shift_rest(ds_dir / f"rec_{k + 1:02d}.csv", 3.0 * k / 7)
    assert not_at_rest(read_dataset(ds_dir)) == []
    _bend_start(ds_dir / "rec_06.csv", theta0_deg=6.0, phi_deg=240.0)
    assert [b["recording"] for b in not_at_rest(read_dataset(ds_dir))] == ["rec_06"]


def test_rest_reading_from_meta_json(tmp_path):
    """A dataset the rig's protocol wrote names its rest reading: a start there is at rest even
    when the IMU reads a tilt upright (a tilted mount), and the median is not needed."""
    ds_dir = tmp_path / "ds"
    generate(ds_dir, [], seed=2, n_recordings=3, duration_s=10.0, temperatures=False)
    meta = json.loads((ds_dir / "meta.json").read_text())
    meta["rest_tilt_deg"] = [3.0, 0.0]  # not where this rig's IMU rests (~0)
    (ds_dir / "meta.json").write_text(json.dumps(meta))
    found = not_at_rest(read_dataset(ds_dir))
    assert len(found) == 3 and all(b["tilt_off_deg"] == pytest.approx(3.0, abs=0.5) for b in found)
    assert all("meta.json" in b["why"] for b in found)


@pytest.mark.slow
def test_neck_gap_excludes_and_reports_a_recording_not_at_rest(tmp_path, capsys):
    ds_dir = tmp_path / "ds"
    generate(ds_dir, [], seed=11, n_recordings=5, duration_s=14.0, temperatures=False)
    _bend_start(ds_dir / "rec_02.csv", theta0_deg=9.0, phi_deg=300.0)
    out = tmp_path / "report.json"
    assert gap_main([str(ds_dir), "--json", str(out), "--no-plots"]) == 0
    cap = capsys.readouterr()
    rep = json.loads(out.read_text())
    assert [b["recording"] for b in rep["not_at_rest"]] == ["rec_02"]
    assert rep["not_at_rest"][0]["tilt_off_deg"] > 5.0
    assert "rec_02 does not start at rest" in cap.err and "excluded" in cap.err
    assert "EXCLUDED 1 recording" in cap.out


def test_neck_gap_refuses_a_dataset_with_no_start_at_rest(tmp_path, capsys):
    ds_dir = tmp_path / "ds"
    generate(ds_dir, [], seed=1, n_recordings=2, duration_s=10.0, temperatures=True)
    for f in ("rec_01.csv", "rec_02.csv"):
        _bend_start(ds_dir / f, theta0_deg=0.0, warm_K=20.0)
    out = tmp_path / "report.json"
    assert gap_main([str(ds_dir), "--json", str(out), "--no-plots"]) == 2
    assert "no recording starts at rest" in capsys.readouterr().err and not out.exists()
