"""Replay a rig's recordings in ``NeckTrack-v0`` built from a diagnosis' corrected-model files.

``python -m neck_env.gap.replay DATASET_DIR REPORT.json [--json OUT.json]`` prints, per
recording, the RMS tilt error (per tilt component, deg) between the recording and the env loaded from
``REPORT_params.json`` / ``REPORT_effects.json``, and the same for the defaults' rig: how far
the exported model reproduces this rig (``docs/gap.md``, method item 11).

The env is made at the recording's sample period (the default 20 Hz step moves a switching edge
by up to 40 ms, which a short pulse feels) and without the task's energy budget and
over-temperature cut; each row's currents hold until the next row, where the pose is compared.
The env's head pose read as the diagnosis reads it (the sensor chain's settled accelerometer
tilt, through the exported ``imu_misalignment``'s mount where there is one) plus the IMU zero
offset fitted with the exported model (the report's ``export.sensors``) is compared with the
recorded tilt. Where the recordings hold thermistor columns, the springs' temperatures
(``info``, read through the thermistor lag fitted with it) are compared too, each reading with the mean of its channel's difference before the recording's
first command taken off (a thermistor's offset is no part of the model).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Mapping, Sequence

import gymnasium as gym
import numpy as np

from .. import effects as fx
from ..params import NeckParams
from ..recording import Recording, read_dataset
from ..sensors import thermistor_lag_series
from .model import imu_tilt, tilt_vec

__all__ = ["replay", "replay_dataset", "report_offset_deg",
           "report_thermistor_lag_s", "main"]


def replay(rec: Recording, params: NeckParams | str | Path | None,
           effects: Mapping[str, Mapping[str, float]] | None = None,
           offset_deg: Sequence[float] = (0.0, 0.0), thermistor_lag_s: float = 0.0) -> dict:
    """``NeckTrack-v0`` (``params``: a NeckParams, a params JSON path, or None for the
    defaults) replaying ``rec``'s commanded currents: ``{"tilt_deg": RMS tilt error per
    component, "temperature_C": RMS thermistor error or None without readings}``."""
    dt = float(np.median(np.diff(rec.t)))
    with warnings.catch_warnings():
        # v0 is the one that applies the recorded currents as they are (v1 adds the firmware)
        warnings.filterwarnings("ignore", ".*NeckTrack-v0 is out of date")
        env = gym.make("NeckTrack-v0", params=params, effects=dict(effects or {}), dt=dt,
                       energy_budget_J=float("inf"), cutoff_C=float("inf"))
    core = env.unwrapped.core
    try:
        _, info0 = env.reset(seed=0)
        infos, poses = [], np.empty((rec.n - 1, 3))
        for k in range(rec.n - 1):
            infos.append(env.step(rec.currents_A[k].astype(np.float32))[4])
            poses[k] = core.pose_rad[0]
    finally:
        env.close()
    mount = fx.imu_mount(effects or {})
    sim = np.stack(imu_tilt(poses, mount), -1) + np.asarray(offset_deg)
    meas = np.stack(tilt_vec(rec.theta_deg[1:], rec.phi_deg[1:]), -1)
    out = {"tilt_deg": float(np.sqrt(np.mean((sim - meas) ** 2))), "temperature_C": None}
    T = rec.temperatures_C
    if T is not None and np.isfinite(T).any():
        true = np.vstack([np.asarray(info0["temperatures_C"], float)[None],
                          np.array([i["temperatures_C"] for i in infos], float)])
        read = np.empty_like(true)
        thermistor_lag_series(true, rec.t, float(thermistor_lag_s), read)
        err = T - read
        on = rec.currents_A.any(axis=1)
        before = np.arange(rec.n) < (np.argmax(on) if on.any() else rec.n)
        for j in range(3):
            ok = np.isfinite(err[:, j])
            if (ok & before).any():
                err[:, j] -= err[ok & before, j].mean()
        out["temperature_C"] = float(np.sqrt(np.nanmean(err ** 2)))
    return out


def _export_sensors(report: Mapping) -> Mapping | None:
    """The exported fit's sensors (``export.sensors``); None in a report older than them."""
    return (report.get("export") or {}).get("sensors")


def report_offset_deg(report: Mapping) -> np.ndarray:
    """The IMU zero offset (x, y, deg) fitted with the exported model (``export.sensors``; a
    report written before 2026-12-07 has only the nominal refit's, in ``calibration``)."""
    sensors = _export_sensors(report)
    if sensors is not None:
        return np.array([sensors["offset_x_deg"], sensors["offset_y_deg"]])
    cal = report["calibration"]["params"]
    return np.array([cal["offset_x_deg"]["value"], cal["offset_y_deg"]["value"]])


def report_thermistor_lag_s(report: Mapping) -> float:
    """The thermistors' lag fitted with the exported model (0 s where none was fitted; as
    ``report_offset_deg``, the nominal refit's in an older report)."""
    sensors = _export_sensors(report)
    if sensors is not None:
        return float(sensors["thermistor_lag_s"])
    return float(report["calibration"]["params"].get("thermistor_lag_s", {}).get("value", 0.0))


def _beside(path: str, report_dir: Path | None) -> Path:
    """A file the report names: as written (relative to where neck-gap ran), else beside the
    report (the folder moved, or replayed from elsewhere)."""
    p = Path(path)
    if not p.exists() and report_dir is not None and (report_dir / p.name).exists():
        return report_dir / p.name
    return p


def replay_dataset(dataset: str | Path, report: Mapping | str | Path,
                   recordings: int | None = None) -> dict[str, np.ndarray]:
    """Per-recording replay errors of the report's exported model and of the defaults:
    ``{"names", "exported_deg", "defaults_deg", "exported_C", "defaults_C"}`` (temperatures
    NaN where a recording has no thermistor readings; the first ``recordings`` only if given)."""
    report_dir = None
    if not isinstance(report, Mapping):
        report_dir = Path(report).parent
        report = json.loads(Path(report).read_text())
    outputs = report.get("outputs") or {}
    if "params" not in outputs:
        raise ValueError("the report names no exported model (outputs.params): write it with "
                         "neck-gap DATASET --json REPORT.json")
    if "calibration" not in report and _export_sensors(report) is None:
        raise ValueError("the report has no calibration (the IMU zero offset the replay adds): "
                         "is it a neck-gap report?")
    params = _beside(outputs["params"], report_dir)
    effects = (json.loads(_beside(outputs["effects"], report_dir).read_text())
               if "effects" in outputs else {})
    recs = read_dataset(dataset).recordings[:recordings]
    off, lag = report_offset_deg(report), report_thermistor_lag_s(report)
    ex = [replay(r, params, effects, off, lag) for r in recs]
    de = [replay(r, None, None, (0.0, 0.0), lag) for r in recs]
    temps = lambda rs: np.array([np.nan if x["temperature_C"] is None else x["temperature_C"]
                                 for x in rs])
    return {"names": [r.name for r in recs],
            "exported_deg": np.array([x["tilt_deg"] for x in ex]),
            "defaults_deg": np.array([x["tilt_deg"] for x in de]),
            "exported_C": temps(ex), "defaults_C": temps(de)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neck_env.gap.replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", help="the recordings' folder the report was made from")
    ap.add_argument("report", help="the neck-gap JSON report (its outputs name the model files)")
    ap.add_argument("--recordings", type=int, default=None, help="replay only the first N")
    ap.add_argument("--json", default=None, metavar="PATH",
                    help="also write the errors per recording and their medians here")
    a = ap.parse_args(argv)
    try:
        out = replay_dataset(a.dataset, a.report, a.recordings)
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{'recording':16s} {'exported (deg)':>15s} {'defaults (deg)':>15s} "
          f"{'exported (C)':>13s} {'defaults (C)':>13s}")
    rows = zip(out["names"], out["exported_deg"], out["defaults_deg"], out["exported_C"],
               out["defaults_C"])
    for n, x, d, xc, dc in rows:
        print(f"{n:16s} {x:15.3f} {d:15.3f} {xc:13.2f} {dc:13.2f}")
    med = lambda k: np.nanmedian(out[k]) if np.isfinite(out[k]).any() else np.nan
    print(f"{'median':16s} {med('exported_deg'):15.3f} {med('defaults_deg'):15.3f} "
          f"{med('exported_C'):13.2f} {med('defaults_C'):13.2f}")
    if a.json:
        keys = ("exported_deg", "defaults_deg", "exported_C", "defaults_C")
        num = lambda v: None if not np.isfinite(v) else round(float(v), 4)  # JSON has no NaN
        doc = {"dataset": str(a.dataset), "report": str(a.report),
               "recordings": [{"name": n, **{k: num(out[k][i]) for k in keys}}
                              for i, n in enumerate(out["names"])],
               "median": {k: num(med(k)) for k in keys},
               "doc": "RMS error per tilt component (deg) and per thermistor (C, each channel's "
                      "offset before the first command taken off) of NeckTrack-v0 built from "
                      "the report's export and of the defaults, replaying each recording's "
                      "commanded currents; null where a recording has no thermistor readings"}
        try:
            Path(a.json).write_text(json.dumps(doc, indent=2) + "\n")
        except OSError as e:
            print(f"error: cannot write {a.json}: {e}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
