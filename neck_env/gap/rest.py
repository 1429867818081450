"""Recordings that do not start at rest: found, measured, and kept out of the diagnosis.

The diagnosis simulates every recording from rest (``neck_env.experiments.REST``: upright,
springs at ambient). A recording that starts with the neck still bent, or the springs still
warm, from the one before would leave a residual no catalogued effect explains -- an inflated
gap, or a false ``unexplained``. :func:`not_at_rest` finds them from the data alone:

* **tilt**: the mean tilt vector over the first ``window_s`` against the dataset's rest reading
  (``meta.json``'s ``rest_tilt_deg`` when the rig's ``protocol`` command wrote it, else read
  from the recordings' starts: most recordings of a protocol start at rest). Read from the
  starts, the rest reading may move slowly through the session -- springs taking a permanent
  set as they fatigue, an IMU whose bias drifts -- so it is a robust straight line through the
  starts in file order (Cauchy loss at the rig's own criterion: a bent start weighs almost
  nothing), not one value: a slow move of the rest is not a start away from rest, and the
  diagnosis has its own account of a moving rest reading (drift nuisance, ``unexplained``);
* **temperature** (measured ``T1..T3`` only, never an estimate): the hottest spring over the
  first ``window_s`` against ``meta.json``'s ``ambient_C`` (else the coolest start).

A start counts as away from rest beyond ``SLACK`` times the rig's own criterion (the rig waits
until it is within the criterion; the slack leaves room for the sensors' noise). ``neck-gap``
excludes those recordings with a warning and lists them in the report as ``"not_at_rest"``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from ..experiments import REST, RestCriterion
from ..recording import Dataset, Recording

__all__ = ["not_at_rest", "without", "rest_reading", "SLACK", "WINDOW_S"]

SLACK = 2.0
WINDOW_S = 0.5
MIN_FOR_TREND = 5  # fewer starts: one rest reading (their median); a line through 3-4 bends too easily


def _start(rec: Recording, window_s: float) -> np.ndarray:
    return rec.t <= rec.t[0] + window_s


def _start_tilt(rec: Recording, window_s: float) -> np.ndarray:
    """Mean tilt vector (deg) over the start window."""
    sel = _start(rec, window_s)
    ph = np.radians(rec.phi_deg[sel])
    th = rec.theta_deg[sel]
    return np.array([np.mean(th * np.cos(ph)), np.mean(th * np.sin(ph))])


def rest_reading(ds: Dataset, window_s: float = WINDOW_S,
                 criterion: RestCriterion = REST) -> tuple[np.ndarray, str]:
    """The rest tilt vector (deg) at each recording's start, (R, 2), and where it comes from."""
    R = len(ds.recordings)
    given = ds.meta.get("rest_tilt_deg")
    if given is not None:
        v = np.asarray(given, float)
        if v.shape == (2,) and np.all(np.isfinite(v)):
            return np.tile(v, (R, 1)), "meta.json rest_tilt_deg"
    starts = np.array([_start_tilt(r, window_s) for r in ds.recordings])
    median = np.median(starts, axis=0)
    if R < MIN_FOR_TREND:
        return np.tile(median, (R, 1)), "median of the recordings' starts"
    u = np.linspace(-0.5, 0.5, R)[:, None]  # file order; recorded time is not in the format

    def misfit(p: np.ndarray) -> np.ndarray:
        return (starts - (p[:2] + u * p[2:])).ravel()

    # from the median with no slope: the bent starts begin (and stay) far out on the loss's tail
    fit = least_squares(misfit, np.r_[median, 0.0, 0.0], loss="cauchy",
                        f_scale=criterion.tilt_deg)
    return fit.x[:2] + u * fit.x[2:], "the recordings' starts, a slowly moving rest allowed"


def not_at_rest(ds: Dataset, criterion: RestCriterion = REST, window_s: float = WINDOW_S,
                slack: float = SLACK) -> list[dict]:
    """The recordings of ``ds`` that do not start at rest, in dataset order: each
    ``{"recording", "tilt_off_deg", "temperature_excess_K" (None without T columns), "why"}``."""
    rest, source = rest_reading(ds, window_s, criterion)
    warm: list[float | None] = []
    for r in ds.recordings:
        block = None if r.temperatures_C is None else r.temperatures_C[_start(r, window_s)]
        read = None if block is None else np.isfinite(block)
        if block is None or not read.any():
            warm.append(None)
        else:  # the warmest spring with a reading (a thermistor may be missing or drop out)
            means = np.where(read, block, 0.0).sum(axis=0) / np.maximum(read.sum(axis=0), 1)
            warm.append(float(means[read.any(axis=0)].max()))
    known = [w for w in warm if w is not None]
    ambient = ds.meta.get("ambient_C")
    if ambient is None and known:
        ambient = min(known)
    out = []
    for r, w, rest_r in zip(ds.recordings, warm, rest):
        off = float(np.hypot(*(_start_tilt(r, window_s) - rest_r)))
        excess = None if (w is None or ambient is None) else w - float(ambient)
        why = []
        if off > slack * criterion.tilt_deg:
            th0 = float(np.mean(r.theta_deg[_start(r, window_s)]))
            why.append(f"starts {off:.1f} deg from the rest tilt ({source}; theta {th0:.1f} deg "
                       f"in the first {window_s:g} s)")
        if excess is not None and excess > slack * criterion.temperature_K:
            why.append(f"a spring starts {excess:.1f} K above ambient ({float(ambient):g} C)")
        if why:
            out.append({"recording": r.name, "tilt_off_deg": round(off, 3),
                        "temperature_excess_K": None if excess is None else round(excess, 2),
                        "why": "; ".join(why)})
    return out


def without(ds: Dataset, names: list[str]) -> Dataset:
    """``ds`` without the named recordings (same order, same meta)."""
    drop = set(names)
    return replace(ds, recordings=[r for r in ds.recordings if r.name not in drop])
