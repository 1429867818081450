"""The recording format (docs/recording-format.md): reading, validation errors naming file and line,
datasets in name order with meta.json, and the flushing writer."""

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from neck_env.recording import (REQUIRED_COLUMNS, RecordingError, RecordingWriter, read_dataset,
                                read_recording, write_recording)

GOOD = textwrap.dedent("""\
    t,i1,i2,i3,theta_deg,phi_deg,T1,T2,T3,note
    0.00,0,0,0,0.1,12.0,25.0,25.1,24.9,start
    0.02,5,0,0,0.2,181.0,25.5,25.1,24.9,
    0.04,5,0,0,0.4,361.0,26.0,25.2,25.0,x
    """)


def _write(path, text):
    path.write_text(text)
    return path


def test_read_good_recording(tmp_path):
    rec = read_recording(_write(tmp_path / "rec_01.csv", GOOD))
    assert rec.n == 3 and rec.name == "rec_01"
    np.testing.assert_allclose(rec.t, [0, 0.02, 0.04])
    np.testing.assert_allclose(rec.i1, [0, 5, 5])
    np.testing.assert_allclose(rec.phi_deg, [12.0, 181.0, 1.0])  # wrapped into [0, 360)
    assert rec.temperatures_C.shape == (3, 3)
    assert list(rec.extra) == ["note"]  # unknown columns are kept
    assert rec.extra["note"][0] == "start"


def test_temperatures_optional(tmp_path):
    text = "t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,1,0,0,1,180\n"
    rec = read_recording(_write(tmp_path / "a.csv", text))
    assert rec.temperatures_C is None


@pytest.mark.parametrize("text, fragment, line", [
    ("t,i1,i2,theta_deg,phi_deg\n0,0,0,0,0\n", "missing required column(s) i3", 1),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,0,0,0,0,0\n0.1,0,0,0,0,0\n", "does not increase", 4),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,0,0,0,nan,0\n", "NaN", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,0,0,0,,0\n", "empty", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,0,zero,0,0,0\n", "not a number", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,0,0,0,0\n", "fields", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,-1,0,0,0\n", "negative", 2),
    ("t;i1;i2;i3;theta_deg;phi_deg\n0;0;0;0;0;0\n", "comma-separated", 1),
    # the units' common slips: a current in mA, an Arduino's millis() as t
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.02,0,6500,0,0,0\n", "divide it by 1000", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n20,7,0,0,0,0\n40,7,0,0,1,0\n",
     "median 20 s apart", None),
    ("t,i1,i2,i3,theta_deg,phi_deg\n", "no data rows", None),
    ("", "empty", None),
    ("\n\n", "empty", None),
])
def test_bad_recordings_name_file_and_line(tmp_path, text, fragment, line):
    p = _write(tmp_path / "rec_07.csv", text)
    with pytest.raises(RecordingError) as exc:
        read_recording(p)
    msg = str(exc.value)
    assert "rec_07.csv" in msg and fragment in msg, msg
    assert exc.value.line == line
    if line is not None:
        assert f"line {line}" in msg


def test_missing_imu_readings_filled_over_short_gaps(tmp_path):
    # the tilt vector is interpolated: phi crosses 0/360 the short way, theta is the vector's
    text = ("t,i1,i2,i3,theta_deg,phi_deg\n"
            "0.00,0,0,0,2.0,350\n"
            "0.02,0,0,0,,\n"
            "0.04,0,0,0,2.0,10\n"
            "0.06,0,0,0,3.0,nan\n"
            "0.08,0,0,0,3.0,90\n")
    p = _write(tmp_path / "rec_01.csv", text)
    with pytest.raises(RecordingError, match="line 3.*empty"):
        read_recording(p)  # strict by default: the format requires every reading
    rec = read_recording(p, imu_gap_max_s=0.05)
    np.testing.assert_array_equal(rec.imu_filled, [False, True, False, True, False])
    assert rec.phi_deg[1] == pytest.approx(0.0, abs=1e-9)
    assert rec.theta_deg[1] == pytest.approx(2.0 * np.cos(np.radians(10.0)))
    assert rec.theta_deg[3] == 3.0  # read: only phi was missing
    v = (np.array([2 * np.cos(np.radians(10)), 2 * np.sin(np.radians(10))]) + [0.0, 3.0]) / 2
    assert rec.phi_deg[3] == pytest.approx(np.degrees(np.arctan2(v[1], v[0])))
    assert read_dataset(tmp_path, imu_gap_max_s=0.05).recordings[0].imu_filled.sum() == 2
    assert read_recording(_write(tmp_path / "b.csv", GOOD), imu_gap_max_s=0.5).imu_filled is None
    # at the ends the nearest reading is held
    ends = read_recording(_write(tmp_path / "c.csv", "t,i1,i2,i3,theta_deg,phi_deg\n"
                                 "0,0,0,0,,\n0.1,0,0,0,1.5,30\n0.2,0,0,0,2,40\n0.3,0,0,0,nan,\n"),
                          imu_gap_max_s=0.25)
    np.testing.assert_allclose(ends.theta_deg, [1.5, 1.5, 2.0, 2.0])
    np.testing.assert_allclose(ends.phi_deg, [30, 30, 40, 40])
    from neck_env.gap.cli import imu_gaps_filled  # what neck-gap reports of them
    from neck_env.recording import Dataset
    assert imu_gaps_filled(Dataset([rec, ends])) == [
        {"recording": "rec_01", "samples": 2, "longest_gap_s": pytest.approx(0.04)},
        {"recording": "c", "samples": 2, "longest_gap_s": pytest.approx(0.1)}]


@pytest.mark.parametrize("text, fragment, line", [
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,1,0\n0.1,0,0,0,,\n0.2,0,0,0,,\n0.3,0,0,0,1,0\n",
     "lines 3-4 (2 rows): the readings around them are 0.3 s apart", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,nan,0\n0.1,0,0,0,nan,0\n0.3,0,0,0,1,0\n",
     "lines 2-3 (2 rows) at the start of the recording: the first reading is 0.3 s away", 2),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,1,0\n0.1,0,0,0,1,0\n0.4,0,0,0,,\n",
     "line 4 (1 row) at the end of the recording: the last reading is 0.3 s away", 4),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,,0\n0.1,0,0,0,1,\n", "missing on every row", None),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,1,0\n0.1,0,0,0,inf,0\n", "finite", 3),
    ("t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,1,0\n0.1,0,0,0,one,0\n", "not a number", 3),
])
def test_missing_imu_readings_refused_where_they_cannot_be_filled(tmp_path, text, fragment, line):
    with pytest.raises(RecordingError) as exc:
        read_recording(_write(tmp_path / "rec_02.csv", text), imu_gap_max_s=0.25)
    assert "rec_02.csv" in str(exc.value) and fragment in str(exc.value), str(exc.value)
    assert exc.value.line == line
    if line is not None:
        assert f"line {line}" in str(exc.value) or f"lines {line}-" in str(exc.value)


def test_dataset_natural_order_and_meta(tmp_path):
    for name in ("rec_10.csv", "rec_2.csv", "rec_1.csv"):
        _write(tmp_path / name, GOOD)
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / "meta.json").write_text(json.dumps({"ambient_C": 22.5, "sample_hz": 50,
                                                    "muscle_azimuth_deg": [180, 60, 300],
                                                    "operator": "kept"}))
    ds = read_dataset(tmp_path)
    assert [r.name for r in ds] == ["rec_1", "rec_2", "rec_10"]
    assert ds.meta["ambient_C"] == 22.5 and ds.meta["operator"] == "kept"
    assert ds.has_temperatures


def test_dataset_errors(tmp_path):
    with pytest.raises(RecordingError, match="no \\*.csv recordings"):
        read_dataset(tmp_path)
    with pytest.raises(RecordingError, match="no such dataset folder"):
        read_dataset(tmp_path / "missing")
    _write(tmp_path / "rec_1.csv", GOOD)
    _write(tmp_path / "rec_2.csv", "t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0,0,0,0,0,0\n")
    with pytest.raises(RecordingError, match=r"rec_2\.csv, line 3"):
        read_dataset(tmp_path)
    (tmp_path / "rec_2.csv").unlink()
    (tmp_path / "meta.json").write_text('{"ambient_C": "warm"}')
    with pytest.raises(RecordingError, match="meta.json.*ambient_C"):
        read_dataset(tmp_path)
    (tmp_path / "meta.json").write_text('{"muscle_azimuth_deg": [1, 2]}')
    with pytest.raises(RecordingError, match="three angles"):
        read_dataset(tmp_path)
    (tmp_path / "meta.json").write_text('{oops')
    with pytest.raises(RecordingError, match="meta.json.*not valid JSON"):
        read_dataset(tmp_path)
    # a wire diameter in mm, not m, names the unit it wants
    (tmp_path / "meta.json").write_text('{"spring_wire_diameter_m": 0.5}')
    with pytest.raises(RecordingError, match=r"spring_wire_diameter_m.*0\.0005 for 0\.5 mm"):
        read_dataset(tmp_path)
    (tmp_path / "meta.json").write_text('{"spring_specific_heat_J_kgK": true}')
    with pytest.raises(RecordingError, match="spring_specific_heat_J_kgK must be a finite number"):
        read_dataset(tmp_path)
    (tmp_path / "meta.json").write_text('{"spring_wire_diameter_m": 0.0005, '
                                        '"spring_specific_heat_J_kgK": 322}')
    assert read_dataset(tmp_path).meta["spring_specific_heat_J_kgK"] == 322


def test_units_at_their_limits_read_and_meta_sample_hz_checked(tmp_path):
    # 40 A and one sample a second are still read: the limits catch a wrong unit, not a rig
    text = "t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n1,40,0,0,1,0\n2,0,0,0,1,0\n"
    rec = read_recording(_write(tmp_path / "rec_1.csv", text))
    assert rec.currents_A.max() == 40.0
    (tmp_path / "meta.json").write_text(json.dumps({"sample_hz": 2.5}))
    assert read_dataset(tmp_path).meta["sample_hz"] == 2.5  # 1 s against 0.4 s: inside x3
    (tmp_path / "meta.json").write_text(json.dumps({"sample_hz": 50}))
    with pytest.raises(RecordingError, match=r"meta\.json.*sample_hz 50.*rec_1\.csv's are a "
                                             r"median 1 s apart"):
        read_dataset(tmp_path)
    n = 10
    cols = {"t": np.arange(n) * 0.02, "i1": np.full(n, 7.0), "i2": np.zeros(n), "i3": np.zeros(n),
            "theta_deg": np.zeros(n), "phi_deg": np.zeros(n)}
    with pytest.raises(ValueError, match="milliamperes"):
        write_recording(tmp_path / "ma.csv", dict(cols, i1=np.full(n, 7000.0)))
    with pytest.raises(ValueError, match="millis"):
        write_recording(tmp_path / "ms.csv", dict(cols, t=cols["t"] * 1000))
    assert not (tmp_path / "ma.csv").exists() and not (tmp_path / "ms.csv").exists()
    w = RecordingWriter(tmp_path / "live.csv")
    with pytest.raises(ValueError, match="row 1: commanded current i3 = 7000 A"):
        w.write(t=0.0, i1=0, i2=0, i3=7000, theta_deg=0, phi_deg=0)
    w.close()
    assert (tmp_path / "live.csv").read_text().splitlines() == [",".join(REQUIRED_COLUMNS)]


def test_write_read_round_trip(tmp_path):
    n = 50
    t = np.arange(n) * 0.02
    cols = {"t": t, "i1": np.where(t < 0.5, 6.0, 0.0), "i2": np.zeros(n), "i3": np.zeros(n),
            "theta_deg": np.linspace(0, 10, n), "phi_deg": np.full(n, 365.5),
            "T1": np.full(n, 30.0), "T2": np.full(n, 25.0), "T3": np.full(n, 25.0),
            "ax_g": np.linspace(-1, 1, n)}
    p = write_recording(tmp_path / "r.csv", cols)
    rec = read_recording(p)
    np.testing.assert_allclose(rec.t, t)
    np.testing.assert_allclose(rec.theta_deg, cols["theta_deg"])
    np.testing.assert_allclose(rec.phi_deg, 5.5)
    np.testing.assert_allclose(rec.extra["ax_g"], cols["ax_g"])
    p2 = write_recording(tmp_path / "r2.csv", rec)
    assert read_recording(p2).columns().keys() == rec.columns().keys()
    with pytest.raises(ValueError, match="strictly increasing"):
        write_recording(tmp_path / "bad.csv", dict(cols, t=t[::-1]))


def test_writer_validates_and_flushes(tmp_path):
    p = tmp_path / "live.csv"
    w = RecordingWriter(p, list(REQUIRED_COLUMNS) + ["T1", "T2", "T3"], flush_s=0.0)
    w.write(t=0.0, i1=0, i2=0, i3=0, theta_deg=0.0, phi_deg=0.0, T1=25, T2=25, T3=25)
    w.write({"t": 0.02, "i1": 7, "i2": 0, "i3": 0, "theta_deg": 0.1, "phi_deg": 180.0,
             "T1": 26, "T2": 25, "T3": 25})
    # flushed as it goes: another reader sees both rows before close
    assert read_recording(p).n == 2
    with pytest.raises(ValueError, match="does not increase"):
        w.write(t=0.01, i1=0, i2=0, i3=0, theta_deg=0, phi_deg=0, T1=25, T2=25, T3=25)
    with pytest.raises(ValueError, match="finite theta_deg"):
        w.write(t=0.04, i1=0, i2=0, i3=0, theta_deg=float("nan"), phi_deg=0, T1=25, T2=25, T3=25)
    with pytest.raises(ValueError, match="T2 = inf is infinite"):
        w.write(t=0.04, i1=0, i2=0, i3=0, theta_deg=0, phi_deg=0, T1=25, T2=math.inf, T3=25)
    with pytest.raises(ValueError, match="unknown column"):
        w.write(t=0.04, i1=0, i2=0, i3=0, theta_deg=0, phi_deg=0, bogus=1)
    # a thermistor that drops out (open or shorted: NaN) or is not read (None) does not end
    # the recording: its cell is left empty and reads back as a missing reading
    w.write(t=0.04, i1=7, i2=0, i3=0, theta_deg=0.2, phi_deg=180, T1=27, T2=float("nan"), T3=25)
    w.write(t=0.06, i1=7, i2=0, i3=0, theta_deg=0.3, phi_deg=180, T1=28, T3=25)
    w.close()
    assert p.read_text().splitlines()[-1].endswith(",28.0,,25.0")
    rec = read_recording(p)
    assert rec.n == 4 and rec.temperatures_C[1, 0] == 26
    np.testing.assert_array_equal(np.isnan(rec.temperatures_C[:, 1]), [False, False, True, True])


def test_thermistors_on_some_springs_and_missing_readings(tmp_path):
    """Any of T1..T3 (one per fitted thermistor); an empty or NaN cell is a missing reading,
    text or an infinity in a thermistor column is still an error."""
    text = ("t,i1,i2,i3,theta_deg,phi_deg,T3\n0,0,0,0,0,0,25.0\n0.1,5,0,0,1,180,\n"
            "0.2,5,0,0,2,180,nan\n0.3,5,0,0,3,180,27.5\n")
    rec = read_recording(_write(tmp_path / "rec_01.csv", text))
    assert rec.temperatures_C.shape == (4, 3)
    assert np.isnan(rec.temperatures_C[:, :2]).all()
    np.testing.assert_array_equal(rec.temperatures_C[[0, 3], 2], [25.0, 27.5])
    assert np.isnan(rec.temperatures_C[1:3, 2]).all()
    # a channel never read gets no column when written back; the rest round-trips
    write_recording(tmp_path / "back" / "rec_01.csv", rec)
    assert (tmp_path / "back" / "rec_01.csv").read_text().splitlines()[0] == "t,i1,i2,i3,theta_deg,phi_deg,T3"
    back = read_recording(tmp_path / "back" / "rec_01.csv")
    np.testing.assert_array_equal(np.isnan(back.temperatures_C), np.isnan(rec.temperatures_C))
    # a dataset has temperatures when any recording holds a reading
    plain = "t,i1,i2,i3,theta_deg,phi_deg\n0,0,0,0,0,0\n0.1,1,0,0,1,180\n"
    _write(tmp_path / "back" / "rec_02.csv", plain)
    assert read_dataset(tmp_path / "back").has_temperatures
    unread = "t,i1,i2,i3,theta_deg,phi_deg,T1\n0,0,0,0,0,0,\n0.1,1,0,0,1,180,nan\n"
    (tmp_path / "never").mkdir()
    _write(tmp_path / "never" / "rec_01.csv", unread)
    assert not read_dataset(tmp_path / "never").has_temperatures
    for bad, fragment in (("warm", "not a number: 'warm'"), ("inf", "values must be finite")):
        p = _write(tmp_path / f"bad_{bad}.csv", text.replace("27.5", bad))
        with pytest.raises(RecordingError, match=fragment) as exc:
            read_recording(p)
        assert exc.value.line == 5
    with pytest.raises(ValueError, match="T3 has infinite values"):
        write_recording(tmp_path / "inf.csv", dict(rec.columns(), T3=np.full(rec.n, np.inf)))


def test_writer_crash_loses_at_most_the_last_second(tmp_path):
    """A process killed mid-recording leaves every row older than the flush interval on disk."""
    p = tmp_path / "crash.csv"
    code = textwrap.dedent(f"""
        import os, time
        from neck_env.recording import RecordingWriter
        w = RecordingWriter({str(p)!r}, flush_s=1.0)
        for k in range(300):  # 6 s of data at 50 Hz, written instantly
            w.write(t=k * 0.02, i1=0, i2=0, i3=0, theta_deg=0.0, phi_deg=0.0)
        os._exit(1)  # crash: no close, no atexit, no buffer flush
        """)
    subprocess.run([sys.executable, "-c", code], check=False)
    lines = p.read_text().splitlines()
    rows = len(lines) - 1
    assert rows >= 300 - 50 - 1, rows  # at most the last second (50 rows) lost
