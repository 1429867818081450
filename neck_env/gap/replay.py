"""Replay a rig's recordings in ``NeckTrack-v0`` built from a diagnosis' corrected-model files.

``python -m neck_env.gap.replay DATASET_DIR REPORT.json`` prints, per recording, the RMS tilt
error (per tilt component, deg) between the recording and the env loaded from
``REPORT_params.json`` / ``REPORT_effects.json``, and the same for the defaults' rig: how far
the exported model reproduces this rig (``docs/gap.md``, method item 11).

The env is made at the recording's sample period (the default 20 Hz step moves a switching edge
by up to 40 ms, which a short pulse feels) and without the task's energy budget and
over-temperature cut; each row's currents hold until the next row, where the pose is compared.
The env's true tilt (``info``) plus the report's fitted IMU zero offset is compared with the
recorded tilt: a sensor effect in the files (``imu_misalignment``) changes what the env's IMU
reads, not ``info``, so the replay leaves it out.
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

from ..params import NeckParams
from ..recording import Recording, read_dataset
from .model import tilt_vec

__all__ = ["replay_gap_deg", "replay_dataset", "report_offset_deg", "main"]


def replay_gap_deg(rec: Recording, params: NeckParams | str | Path | None,
                   effects: Mapping[str, Mapping[str, float]] | None = None,
                   offset_deg: Sequence[float] = (0.0, 0.0)) -> float:
    """RMS tilt error (per component, deg) of ``NeckTrack-v0`` (``params``: a NeckParams, a
    params JSON path, or None for the defaults) replaying ``rec``'s commanded currents."""
    dt = float(np.median(np.diff(rec.t)))
    with warnings.catch_warnings():
        # v0 is the one that applies the recorded currents as they are (v1 adds the firmware)
        warnings.filterwarnings("ignore", ".*NeckTrack-v0 is out of date")
        env = gym.make("NeckTrack-v0", params=params, effects=dict(effects or {}), dt=dt,
                       energy_budget_J=float("inf"), cutoff_C=float("inf"))
    try:
        env.reset(seed=0)
        infos = [env.step(rec.currents_A[k].astype(np.float32))[4] for k in range(rec.n - 1)]
    finally:
        env.close()
    sim = np.stack(tilt_vec(np.array([i["theta_deg"] for i in infos]),
                            np.array([i["phi_deg"] for i in infos])), -1) + np.asarray(offset_deg)
    meas = np.stack(tilt_vec(rec.theta_deg[1:], rec.phi_deg[1:]), -1)
    return float(np.sqrt(np.mean((sim - meas) ** 2)))


def report_offset_deg(report: Mapping) -> np.ndarray:
    """The IMU zero offset (x, y, deg) a diagnosis report fitted."""
    cal = report["calibration"]["params"]
    return np.array([cal["offset_x_deg"]["value"], cal["offset_y_deg"]["value"]])


def _sensor_free(effects: Mapping) -> dict:
    return {k: v for k, v in effects.items() if k != "imu_misalignment"}


def replay_dataset(dataset: str | Path, report: Mapping | str | Path,
                   recordings: int | None = None) -> dict[str, np.ndarray]:
    """Per-recording replay errors of the report's exported model and of the defaults:
    ``{"names", "exported_deg", "defaults_deg"}`` (the first ``recordings`` only if given)."""
    if not isinstance(report, Mapping):
        report = json.loads(Path(report).read_text())
    outputs = report.get("outputs") or {}
    if "params" not in outputs:
        raise ValueError("the report names no exported model (outputs.params): write it with "
                         "neck-gap DATASET --json REPORT.json")
    params = Path(outputs["params"])
    effects = json.loads(Path(outputs["effects"]).read_text()) if "effects" in outputs else {}
    recs = read_dataset(dataset).recordings[:recordings]
    off = report_offset_deg(report)
    return {"names": [r.name for r in recs],
            "exported_deg": np.array([replay_gap_deg(r, params, _sensor_free(effects), off)
                                      for r in recs]),
            "defaults_deg": np.array([replay_gap_deg(r, None) for r in recs])}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neck_env.gap.replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", help="the recordings' folder the report was made from")
    ap.add_argument("report", help="the neck-gap JSON report (its outputs name the model files)")
    ap.add_argument("--recordings", type=int, default=None, help="replay only the first N")
    a = ap.parse_args(argv)
    try:
        out = replay_dataset(a.dataset, a.report, a.recordings)
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{'recording':16s} {'exported (deg)':>15s} {'defaults (deg)':>15s}")
    for n, x, d in zip(out["names"], out["exported_deg"], out["defaults_deg"]):
        print(f"{n:16s} {x:15.3f} {d:15.3f}")
    print(f"{'median':16s} {np.median(out['exported_deg']):15.3f} {np.median(out['defaults_deg']):15.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
