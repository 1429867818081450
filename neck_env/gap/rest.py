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

A start off the rest reading is still a start *at rest* when the neck is not moving there and
the springs are cold (:func:`stuck_starts`): a backbone with stiction holds the neck where the
recording before left it (the simulator with the catalogue's 0.02 N m of friction stops 0.8 deg
off upright after a 7 A pulse, 1.9 deg at 0.05 N m), and no wait brings it back. The rig's
``protocol`` names such recordings in ``meta.json`` (``stuck_starts_tilt_deg``); otherwise they
are found from the data. They are kept: the diagnosis simulates them from where they start.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ..experiments import REST, RestCriterion
from ..recording import Dataset, Recording

__all__ = ["not_at_rest", "stuck_starts", "start_tilt", "without", "rest_reading", "SLACK", "WINDOW_S"]

# The reading at rest is the last this long before the first command (at least
# ``MIN_REST_SAMPLES``): a tilt filter started with each recording reads a transient first (the
# independent rig's, tau 0.7 s, from the accelerometer alone), and a mean over the whole wait
# weighs that transient in by how long each recording waited -- another lab's timing waits
# 0.5-3.9 s, and a steady gyro drift then read as scatter (independent 11114, drawn protocol:
# R^2 0.49 over the wait, 0.80 over its last 0.25 s; on 261 other stored datasets no rest
# decision changes). The diagnosis's rest offsets and the repeats' bends both read it here.
REST_READ_S = 0.25
MIN_REST_SAMPLES = 5
SLACK = 2.0
WINDOW_S = 0.5
MIN_FOR_TREND = 5  # fewer starts: one rest reading (their median); a line through 3-4 bends too easily
# the part of a recording before its first command on which a start is judged not moving: long
# enough that a neck still returning from the recording before shows its motion
STILL_MIN_S = 1.0
# starts off the rest reading, at rest there, that show a dataset's neck sticks: one alone can be
# the sensor's noise (a 0.5 s mean of the fused tilt scatters ~0.2 deg; 0.6 deg is 3 sigma)
MIN_STUCK = 2
# a start held off its rest moves before the first command by at most this share of its offset
# (beyond the recordings' common motion; a reading that settles back moves by all of it)
STILL_SHARE = 0.5


def settled_rest(t: np.ndarray, first: int) -> np.ndarray:
    """Which samples of a recording (times ``t``) are its reading at rest before its first
    command at index ``first`` (>= 1): the last ``REST_READ_S`` of the wait, and at least its
    last ``MIN_REST_SAMPLES`` samples."""
    i = np.arange(t.size)
    return (i < first) & ((t >= t[first - 1] - REST_READ_S) | (i >= first - MIN_REST_SAMPLES))


def _start(rec: Recording, window_s: float) -> np.ndarray:
    return rec.t <= rec.t[0] + window_s


def _tilt_xy(rec: Recording) -> np.ndarray:
    """(n, 2) tilt vector (deg, as read) of every sample."""
    ph = np.radians(rec.phi_deg)
    return np.column_stack([rec.theta_deg * np.cos(ph), rec.theta_deg * np.sin(ph)])


def start_tilt(rec: Recording, window_s: float = WINDOW_S) -> np.ndarray:
    """Mean tilt vector (deg, as read) over the start window."""
    return _tilt_xy(rec)[_start(rec, window_s)].mean(axis=0)


def rest_reading(ds: Dataset, window_s: float = WINDOW_S,
                 criterion: RestCriterion = REST) -> tuple[np.ndarray, str]:
    """The rest tilt vector (deg) at each recording's start, (R, 2), and where it comes from."""
    R = len(ds.recordings)
    given = ds.meta.get("rest_tilt_deg")
    if given is not None:
        v = np.asarray(given, float)
        if v.shape == (2,) and np.all(np.isfinite(v)):
            return np.tile(v, (R, 1)), "meta.json rest_tilt_deg"
    starts = np.array([start_tilt(r, window_s) for r in ds.recordings])
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


def _start_excess(rec: Recording, window_s: float, ambient: float | None) -> float | None:
    """The warmest spring with a reading over the start window, K above ``ambient`` (None
    without thermistor readings there or without an ambient)."""
    if rec.temperatures_C is None or ambient is None:
        return None
    block = rec.temperatures_C[_start(rec, window_s)]
    read = np.isfinite(block)
    if not read.any():
        return None
    means = np.where(read, block, 0.0).sum(axis=0) / np.maximum(read.sum(axis=0), 1)
    return float(means[read.any(axis=0)].max()) - float(ambient)


def _ambient(ds: Dataset, window_s: float) -> float | None:
    """meta.json's ``ambient_C``, else the coolest spring at any recording's start."""
    if ds.meta.get("ambient_C") is not None:
        return float(ds.meta["ambient_C"])
    known = [e for e in (_start_excess(r, window_s, 0.0) for r in ds.recordings) if e is not None]
    return min(known) if known else None


def _pre_command_motion(rec: Recording, window_s: float) -> np.ndarray | None:
    """How the tilt vector moves over the part of a recording before its first command (at
    least ``STILL_MIN_S``): the mean of its last ``window_s`` minus that of its first, deg
    (None when that part is shorter)."""
    on = (rec.currents_A > 0).any(axis=1)
    end = rec.t[int(np.argmax(on))] if on.any() else rec.t[-1]
    if end - rec.t[0] < STILL_MIN_S:
        return None
    v = _tilt_xy(rec)
    first = v[rec.t <= rec.t[0] + window_s].mean(axis=0)
    last = v[(rec.t >= end - window_s) & (rec.t < end)].mean(axis=0)
    return last - first


def stuck_starts(ds: Dataset, criterion: RestCriterion = REST, window_s: float = WINDOW_S,
                 slack: float = SLACK) -> dict[str, np.ndarray]:
    """Recordings that start at rest where the backbone held the neck (stiction), by name: the
    start's tilt vector as read (deg). The diagnosis simulates them from there.

    Those ``meta.json`` names (``stuck_starts_tilt_deg``) where it gives the rest reading
    (``rest_tilt_deg``: the rig's protocol wrote it, and judged every start while waiting for
    rest). Else from the data, for the dataset as a whole: when at least ``MIN_STUCK`` starts
    lie more than ``criterion.tilt_deg`` off the rest reading with the neck at rest there (no
    spring with a reading more than ``slack`` times ``criterion.temperature_K`` above ambient,
    and still off when the first command comes, having moved less than ``STILL_SHARE`` of its
    offset beyond the recordings' common motion -- ``_pre_command_motion``), every start at
    rest that way (cold, moved less than that). Not one by one: a neck that sticks after most
    recordings scatters most starts around its rest, and the rest read from them is then
    uncertain by about the dead band; the model reads each start against the reading's fitted
    zero (``model.Model.start_pose``), and a start at the rest reading is then simply upright."""
    return _classify(ds, criterion, window_s, slack).stuck


@dataclass(frozen=True)
class _Starts:
    """What ``stuck_starts`` and ``not_at_rest`` both read off the recordings' starts."""

    rest: np.ndarray  # (R, 2) the rest reading at each start
    source: str  # where the rest reading comes from
    starts: dict[str, np.ndarray]  # each recording's start tilt vector as read
    ambient: float | None  # ``_ambient``
    stuck: dict[str, np.ndarray]  # the held starts (``stuck_starts``)


def _classify(ds: Dataset, criterion: RestCriterion, window_s: float, slack: float) -> _Starts:
    """The starts read once for ``stuck_starts`` and ``not_at_rest``."""
    rest, source = rest_reading(ds, window_s, criterion)
    starts = {r.name: start_tilt(r, window_s) for r in ds.recordings}
    ambient = _ambient(ds, window_s)
    if ds.meta.get("rest_tilt_deg") is not None:
        named = ds.meta.get("stuck_starts_tilt_deg") or {}
        return _Starts(rest, source, starts, ambient,
                       {k: v for k, v in starts.items() if k in named})
    motion = [_pre_command_motion(r, window_s) for r in ds.recordings]
    known = [m for m in motion if m is not None]
    # a sensor settling at the start of each recording (a fused tilt whose filter starts from
    # the accelerometer and then takes up the gyro's bias) moves every start alike: that part
    # of a start's motion is the sensor's, the rest the neck's (or the reading's own noise)
    common = np.median(known, axis=0) if len(known) >= MIN_FOR_TREND else np.zeros(2)
    at_rest, far = [], 0
    for r, m, rest_r in zip(ds.recordings, motion, rest):
        excess = _start_excess(r, window_s, ambient)
        cold = excess is None or excess <= slack * criterion.temperature_K
        if not cold or m is None:
            continue
        off = float(np.hypot(*(starts[r.name] - rest_r)))
        before = float(np.hypot(*(starts[r.name] + m - common - rest_r)))  # at the first command
        # held: it moved little against how far off it is, and is still off when the first
        # command comes (a reading that settles back to the rest within the wait is not held)
        held = float(np.hypot(*(m - common))) <= max(criterion.steady_deg, STILL_SHARE * off)
        if held:
            at_rest.append(r.name)
            far += int(off > criterion.tilt_deg and before > criterion.tilt_deg)
    stuck = {k: starts[k] for k in at_rest} if far >= MIN_STUCK else {}
    return _Starts(rest, source, starts, ambient, stuck)


def not_at_rest(ds: Dataset, criterion: RestCriterion = REST, window_s: float = WINDOW_S,
                slack: float = SLACK) -> list[dict]:
    """The recordings of ``ds`` that do not start at rest, in dataset order: each
    ``{"recording", "tilt_off_deg", "temperature_excess_K" (None without T columns), "why"}``."""
    seen = _classify(ds, criterion, window_s, slack)
    source, ambient = seen.source, seen.ambient
    out = []
    for r, rest_r in zip(ds.recordings, seen.rest):
        off = float(np.hypot(*(seen.starts[r.name] - rest_r)))
        # the warmest spring with a reading (a thermistor may be missing or drop out)
        excess = _start_excess(r, window_s, ambient)
        why = []
        if off > slack * criterion.tilt_deg and r.name not in seen.stuck:
            th0 = float(np.mean(r.theta_deg[_start(r, window_s)]))
            why.append(f"starts {off:.1f} deg from the rest tilt ({source}; theta {th0:.1f} deg "
                       f"in the first {window_s:g} s)")
        if excess is not None and excess > slack * criterion.temperature_K:
            why.append(f"a spring starts {excess:.1f} K above ambient ({ambient:g} C)")
        if why:
            out.append({"recording": r.name, "tilt_off_deg": round(off, 3),
                        "temperature_excess_K": None if excess is None else round(excess, 2),
                        "why": "; ".join(why)})
    return out


def without(ds: Dataset, names: list[str]) -> Dataset:
    """``ds`` without the named recordings (same order, same meta)."""
    drop = set(names)
    return replace(ds, recordings=[r for r in ds.recordings if r.name not in drop])
