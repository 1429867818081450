"""``python -m neck_env.rig`` against the Python fake firmware (fast; the HIL tests run it on
the real firmware)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# against the clock (a fake firmware's watchdog and leases): run alone, as the hil tests are
pytestmark = pytest.mark.realtime

pytest.importorskip("serial")

from fake_firmware import FakeFirmware  # noqa: E402

from neck_env.recording import read_dataset  # noqa: E402
from neck_env.rig import cli  # noqa: E402


@pytest.fixture
def fw():
    f = FakeFirmware()
    yield f
    f.close()


def test_help_explains_every_command_and_flag():
    out = subprocess.run([sys.executable, "-m", "neck_env.rig", "--help"], capture_output=True,
                         text=True, check=True).stdout
    for cmd in ("run", "pulse", "protocol", "info", "emulate"):
        assert cmd in out
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.dest != "help":
                assert action.help and len(action.help) > 10, (name, action.dest)


@pytest.mark.parametrize("argv, message", [
    (["run", "--port", "x"], "one of the arguments --policy --controller is required"),
    (["run", "--controller", "pid", "--policy", "p.zip", "--port", "x"], "not allowed with"),
    (["pulse", "--port", "x", "--current", "7", "--muscle", "4"], "invalid choice: 4"),
    (["pulse", "--port", "x", "--current", "-1", "--muscle", "1"], "--current must be > 0"),
    (["run", "--controller", "pid", "--port", "x", "--thermistors", "9"], "must be 0..7"),
])
def test_bad_arguments_exit_2_naming_the_problem(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_errors_exit_1_with_one_line(fw, capsys):
    assert cli.main(["run", "--controller", "nope", "--port", fw.url]) == 1
    assert "unknown controller 'nope'" in capsys.readouterr().err
    assert cli.main(["info", "--port", "/dev/does-not-exist"]) == 1
    assert "cannot open /dev/does-not-exist" in capsys.readouterr().err
    assert cli.main(["pulse", "--port", fw.url, "--current", "7", "--muscle", "1",
                     "--seconds", "12", "--no-cooldown"]) == 1
    assert "on-time cap of 10 s" in capsys.readouterr().err
    assert fw.relays == 0


def test_info_reports_identity_limits_and_imu(fw, capsys):
    assert cli.main(["info", "--port", fw.url, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["firmware_version"] == "1.1.0" and d["limits"]["heartbeat_timeout_ms"] == 250
    assert d["imu"]["ok"] and d["imu"]["tilt_theta_deg"] == 0.0
    assert d["limits"]["over_temperature_cut_C"] == pytest.approx(110, abs=1)
    assert d["limits"]["firmware_default_cut_C"] == 110 and d["limits"]["host_cutoff_C"] == 160
    assert cli.main(["info", "--port", fw.url]) == 0
    out = capsys.readouterr().out
    assert "IMU: accel" in out
    # the 110 C a user sees is explained, with what the commands will set
    assert "110 C is its default until a host configures it" in out and "--cutoff, default 160 C" in out


def test_emulate_effects_argument():
    assert cli.parse_effects("imu_misalignment,actuation_delay") == {
        "imu_misalignment": {"yaw_deg": 10.0, "tilt_deg": 2.0, "tilt_dir_deg": 0.0},
        "actuation_delay": {"delay_s": 0.3}}
    got = cli.parse_effects('{"imu_misalignment": {"yaw_deg": 12}}')
    assert got["imu_misalignment"]["yaw_deg"] == 12.0
    assert cli.parse_effects(None) == {}
    with pytest.raises(ValueError, match="unknown effect 'draft'"):
        cli.parse_effects("draft")
    with pytest.raises(ValueError, match="yaw_deg = 40 outside its range"):
        cli.parse_effects('{"imu_misalignment": {"yaw_deg": 40}}')
    with pytest.raises(ValueError, match="not valid JSON"):
        cli.parse_effects('{"imu_misalignment": ')


def test_run_records_a_dataset(fw, tmp_path, capsys):
    rc = cli.main(["run", "--controller", "bang_bang", "--port", fw.url, "--episode-s", "1",
                   "--episodes", "2", "--record", str(tmp_path / "ds"), "--no-cooldown",
                   "--json", str(tmp_path / "summary.json")])
    assert rc == 0, capsys.readouterr().err
    ds = read_dataset(tmp_path / "ds")
    assert len(ds) == 2 and all(r.duration_s > 0.8 for r in ds)
    rows = json.loads((tmp_path / "summary.json").read_text())
    assert [r["seed"] for r in rows] == [0, 1] and all(r["rmse_deg"] >= 0 for r in rows)
    assert fw.relays == 0


def test_recorded_meta_names_the_rig(fw, tmp_path):
    assert cli.main(["run", "--controller", "zero", "--port", fw.url, "--episode-s", "0.5",
                     "--record", str(tmp_path), "--no-cooldown"]) == 0
    meta = read_dataset(tmp_path).meta
    assert meta["rig"]["firmware_version"] == "1.1.0" and meta["rig"]["port"] == fw.url
    assert "T1_est" in meta["rig"]["temperatures"] and meta["ambient_C"] == 25.0
