"""Measured currents (``i1_meas``, ``i2_meas``, ``i3_meas``): what flowed against what was commanded.

The commanded current (``i1..i3``) is what the host asked for. Relay and link latency
(``actuation_delay``) and a supply that cannot hold its setpoint (``supply_limit``) act
downstream of it, and reach the tilt only through the springs' heat, where a later
transformation, a softer band or a larger heat capacity can look the same (the report's
``ambiguous``). A current sensor on the springs' leads sees both directly, so where a dataset
has one the diagnosis measures them instead of inferring them, without any model:

* **Lag.** At every switching edge of a muscle's command (off -> on, on -> off) the time until
  its measured current crosses half of the step. Their median is the actuation lag; it is
  ``found`` when it reaches ``max(DELAY_MIN_S, DELAY_MIN_SAMPLES / sample rate)`` on at least
  three edges and the lower quartile lags by a sample or more, and ``not found`` when the
  median stays under that.
* **Shortfall.** On each pulse's plateau (the command steady for ``SETTLE_S`` after the
  measured lag) the measured current over the commanded, per setpoint. A current-regulated
  supply holds its setpoint whatever the springs' resistance does, so the ratio is the
  sensor's gain, the same at every setpoint and flat through a pulse. A supply at its voltage
  limit delivers V / R instead: less at the higher setpoints (the ratio falls with the
  setpoint), and a current that changes through the pulse as the springs' resistance changes
  with their phase. Either signature, beyond ``SHORTFALL_MIN`` and the sensor's noise, or every
  setpoint more than ``GAIN_TOL`` short (more than a current sensor's gain is off), is a
  ``found`` limit; ratios flat and within ``GAIN_TOL`` of 1 are ``not found``; anything
  between is ``undecided`` (e.g. one setpoint, a steady ratio of 0.93: a limit or a sensor
  gain). A current above the command by more than ``GAIN_TOL`` (a duty-switched supply read
  sample by sample, a sensor scaled wrongly) leaves it ``undecided``.

Samples where a commanded muscle carries no current at all (relay not closing, a firmware
cut-off or over-temperature cut) are counted and reported, not read as a limit. The sensor's
zero is taken where the command has been off for ``QUIET_S`` (longer than any catalogued
delay). A ``nan`` or empty cell is a missing reading; a column that holds text is reported and
not used (the rest of the diagnosis is unaffected).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np

from ..recording import Dataset, Recording

COLUMNS = ("i1_meas", "i2_meas", "i3_meas")

# the catalogue's smallest delay is 0.1 s; half of it separates a relay's ~10 ms from a delay
# that moves the tilt, and two samples keep the sample clock's skew out of it
DELAY_MIN_S = 0.05
DELAY_MIN_SAMPLES = 2
MIN_EDGES = 3
SEARCH_S = 2.0  # an edge whose current has not crossed half its step by then did not follow it
QUIET_S = 1.5  # the command off this long: the sensor reads its zero (catalogue delay <= 1 s)
SETTLE_S = 0.3  # after the lag, before a plateau sample counts
NO_FLOW = 0.2  # measured below this share of the command: nothing flowed (not a limit)
# a Hall or shunt current sensor's gain is good to a few per cent (ACS712: +-1.5 %); a
# limit must move the current by more than that between setpoints or through a pulse
SHORTFALL_MIN = 0.03
GAIN_TOL = 0.10
MIN_PLATEAU = 5  # samples per pulse plateau before its start/end are compared
SETPOINT_STEP_A = 0.05  # setpoints closer than this are the same one


@dataclass(frozen=True)
class Lag:
    """The measured current's lag after the command's switching edges."""

    edges: int
    median_s: float
    q25_s: float
    q75_s: float
    threshold_s: float
    not_following: int  # edges whose current did not cross half its step within SEARCH_S
    verdict: str  # "found", "not found", "undecided"


@dataclass(frozen=True)
class Shortfall:
    """Measured over commanded current on the pulses' plateaus."""

    ratio_by_setpoint: dict[str, float]  # "i1_meas 6.00 A" -> median ratio
    samples_by_setpoint: dict[str, int]
    fall_across_setpoints: float  # median over channels of 1 - ratio(highest) / ratio(lowest)
    change_within_pulses: float  # median |end - start| / start of the plateau's current
    no_flow_share: float  # share of commanded-on samples (after the lag) with no current
    verdict: str
    why: str


@dataclass(frozen=True)
class CurrentCheck:
    """The report's ``measured_currents``."""

    columns: tuple[str, ...]
    recordings: int  # recordings with at least one usable column
    sample_hz: float
    zero_A: dict[str, float]  # per column, the reading while the command was off
    lag: Lag | None
    shortfall: Shortfall | None
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def delay(self) -> str:
        return self.lag.verdict if self.lag is not None else "undecided"

    @property
    def limit(self) -> str:
        return self.shortfall.verdict if self.shortfall is not None else "undecided"

    def decides(self) -> dict[str, bool]:
        """Effect name -> named (True) or ruled out (False), for the effects the currents settle."""
        out = {}
        for name, v in (("actuation_delay", self.delay), ("supply_limit", self.limit)):
            if v != "undecided":
                out[name] = v == "found"
        return out

    def to_dict(self) -> dict:
        """Plain JSON (a NaN sample rate, where no column was usable, as None)."""
        d = asdict(self)
        if not math.isfinite(d["sample_hz"]):
            d["sample_hz"] = None
        d["columns"] = list(self.columns)
        d["notes"] = list(self.notes)
        d["decides"] = self.decides()
        return d


def _numeric(rec: Recording, col: str, notes: list[str]) -> np.ndarray | None:
    """The column as floats (NaN for a missing reading), or None with a note when it holds text."""
    raw = rec.extra.get(col)
    if raw is None:
        return None
    arr = np.asarray(raw)
    if arr.dtype.kind in "fiu":
        out = arr.astype(float)
    else:
        out = np.full(arr.shape, np.nan)
        bad = []
        for i, v in enumerate(arr):
            s = str(v).strip()
            if s == "" or s.lower() == "nan":
                continue
            try:
                out[i] = float(s)
            except ValueError:
                bad.append(i)
        if bad:
            notes.append(f"{rec.name or rec.path}: {col} holds text ({str(arr[bad[0]])!r} in data "
                         f"row {bad[0] + 1}, {len(bad)} cells): column not used")
            return None
    out[~np.isfinite(out)] = np.nan
    if not np.isfinite(out).any():
        notes.append(f"{rec.name or rec.path}: {col} has no reading")
        return None
    return out


def _off_for(cmd: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Seconds since the command was last on (inf if never on), per sample."""
    last_on = np.where(cmd > 0, t, -np.inf)
    return t - np.maximum.accumulate(last_on)


def _edge_lags(t: np.ndarray, cmd: np.ndarray, meas: np.ndarray) -> tuple[list[float], int]:
    """Lags of the measured current at each off->on and on->off edge of the command."""
    lags, missed = [], 0
    edges = np.flatnonzero(np.diff(cmd) != 0) + 1
    for j in edges:
        before, after = cmd[j - 1], cmd[j]
        if before > 0 and after > 0:
            continue  # a level change: neither relay edge
        window = (t >= t[j]) & (t <= t[j] + SEARCH_S)
        if after > 0:  # on: the level it reaches is the supply's, not the command's
            seg = meas[window]
            level = np.nanpercentile(seg, 90) if np.isfinite(seg).any() else np.nan
            if not (level > NO_FLOW * after):
                missed += 1
                continue
            cross = np.flatnonzero(window & (meas >= 0.5 * level))
        else:
            pre = meas[max(0, j - 5):j]
            level = np.nanmedian(pre) if np.isfinite(pre).any() else np.nan
            if not (level > NO_FLOW * before):
                continue  # the current had not risen before the command fell: no edge to time
            cross = np.flatnonzero(window & (meas <= 0.5 * level))
        if cross.size == 0:
            missed += 1
            continue
        lags.append(float(t[cross[0]] - t[j]))
    return lags, missed


def check(ds: Dataset) -> CurrentCheck | None:
    """The measured-current evidence of a dataset, or None when no recording has a usable
    ``i1_meas..i3_meas`` column."""
    notes: list[str] = []
    per_rec = []  # (rec, {k: meas})
    for rec in ds.recordings:
        cols = {}
        for k, col in enumerate(COLUMNS):
            m = _numeric(rec, col, notes)
            if m is not None:
                cols[k] = m
        if cols:
            per_rec.append((rec, cols))
    if not per_rec:
        return None if not notes else CurrentCheck((), 0, math.nan, {}, None, None, tuple(notes))
    dts = np.concatenate([np.diff(r.t) for r, _ in per_rec if r.t.size > 1])
    fs = 1.0 / float(np.median(dts)) if dts.size else math.nan
    used = sorted({COLUMNS[k] for _, c in per_rec for k in c})

    # the sensor's zero per column, where the command has been off for a while
    zero = {}
    for k in range(3):
        vals = [c[k][_off_for(r.currents_A[:, k], r.t) >= QUIET_S]
                for r, c in per_rec if k in c]
        vals = np.concatenate(vals) if vals else np.empty(0)
        vals = vals[np.isfinite(vals)]
        if vals.size:
            zero[COLUMNS[k]] = float(np.median(vals))
        elif any(k in c for _, c in per_rec):
            zero[COLUMNS[k]] = 0.0
            notes.append(f"{COLUMNS[k]}: the command is never off for {QUIET_S} s, so the "
                         f"sensor's zero is taken as 0 A")

    lags, missed = [], 0
    for r, c in per_rec:
        for k, m in c.items():
            lk, mk = _edge_lags(r.t, r.currents_A[:, k], m - zero[COLUMNS[k]])
            lags += lk
            missed += mk
    thr = max(DELAY_MIN_S, DELAY_MIN_SAMPLES / fs) if math.isfinite(fs) else DELAY_MIN_S
    lag = None
    if lags:
        q25, med, q75 = (float(v) for v in np.percentile(lags, [25, 50, 75]))
        if len(lags) < MIN_EDGES:
            v = "undecided"
        elif med >= thr and q25 >= (1.0 / fs if math.isfinite(fs) else 0.0):
            v = "found"
        elif med < thr:
            v = "not found"
        else:
            v = "undecided"
        lag = Lag(len(lags), med, q25, q75, thr, missed, v)
    elif missed:
        notes.append(f"no switching edge of the command was followed by its measured current "
                     f"({missed} edges): check the sensor's wiring and the relays")

    settle = (lag.median_s if lag is not None else 0.0) + SETTLE_S
    # per channel and setpoint: each channel's sensor has its own gain, so setpoints are
    # compared within a channel, never across channels
    ratios: dict[tuple[int, float], list[np.ndarray]] = {}
    changes, on_n, none_n = [], 0, 0
    for r, c in per_rec:
        for k, m in c.items():
            cmd = r.currents_A[:, k]
            x = m - zero[COLUMNS[k]]
            edges = np.concatenate([[0], np.flatnonzero(np.diff(cmd) != 0) + 1, [cmd.size]])
            for a, b in zip(edges[:-1], edges[1:]):
                level = cmd[a]
                if level <= 0:
                    continue
                seg = np.flatnonzero(r.t[a:b] >= r.t[a] + settle) + a
                seg = seg[np.isfinite(x[seg])]
                if seg.size == 0:
                    continue
                ratio = x[seg] / level
                flowing = ratio > NO_FLOW
                on_n += seg.size
                none_n += int((~flowing).sum())
                rf = ratio[flowing]
                if rf.size == 0:
                    continue
                ratios.setdefault((k, round(level / SETPOINT_STEP_A) * SETPOINT_STEP_A), []).append(rf)
                if rf.size >= 2 * MIN_PLATEAU:
                    q = max(MIN_PLATEAU, rf.size // 4)
                    start, end = np.median(rf[:q]), np.median(rf[-q:])
                    changes.append(abs(end - start) / start)
    short = None
    if ratios:
        med = {key: float(np.median(np.concatenate(v))) for key, v in sorted(ratios.items())}
        counts = {key: int(sum(a.size for a in v)) for key, v in sorted(ratios.items())}
        falls, spans = [], []
        for k in range(3):
            ks = sorted(sp for (kk, sp) in med if kk == k)
            if len(ks) > 1:
                falls.append(1.0 - med[(k, ks[-1])] / med[(k, ks[0])])
                spans.append((ks[0], ks[-1]))
        fall = float(np.median(falls)) if falls else 0.0
        within = float(np.median(changes)) if changes else 0.0
        best = {k: max(v for (kk, _), v in med.items() if kk == k) for k in {kk for kk, _ in med}}
        over = max(med, key=med.get)
        if med[over] > 1.0 + GAIN_TOL:
            v, why = "undecided", (f"the measured current exceeds the command by "
                                   f"{100 * (med[over] - 1):.0f} % ({COLUMNS[over[0]]} at "
                                   f"{over[1]:.2f} A), more than a sensor's gain is off: a "
                                   f"duty-switched current read sample by sample, or a sensor "
                                   f"scaled wrongly; log the current averaged over the switching "
                                   f"period, in A")
        elif fall > SHORTFALL_MIN:
            lo, hi = min(a for a, _ in spans), max(b for _, b in spans)
            v, why = "found", (f"the current falls short more at the higher setpoints (median "
                               f"over the channels {100 * fall:.0f} % less at the highest than "
                               f"at the lowest, {lo:.2f}-{hi:.2f} A, relative to the command)")
        elif within > SHORTFALL_MIN:
            v, why = "found", (f"the current changes through the pulses by {100 * within:.0f} % "
                               f"(median) at a steady command: a supply at its voltage limit "
                               f"following the springs' resistance")
        elif max(best.values()) < 1.0 - GAIN_TOL:
            v, why = "found", (f"every setpoint of every channel delivers at most "
                               f"{100 * max(best.values()):.0f} % of the command, more than a "
                               f"current sensor's gain is off")
        elif abs(fall) <= SHORTFALL_MIN and within <= SHORTFALL_MIN and all(
                abs(x - 1.0) <= GAIN_TOL for x in med.values()):
            v, why = "not found", (f"the current holds the command at every setpoint (ratios "
                                   f"{min(med.values()):.3f}-{max(med.values()):.3f}; across the "
                                   f"setpoints {100 * fall:+.1f} %) and through the pulses "
                                   f"({100 * within:.1f} %)")
        else:
            v, why = "undecided", ("the ratios neither hold the command nor fall with the "
                                   "setpoint or through the pulses beyond the sensor's gain")
        if not falls and v != "found":
            why += ("; one setpoint per channel only: record pulses at two currents (e.g. 4 and "
                    "8 A) to tell a limit from the sensor's gain")
        short = Shortfall({f"{COLUMNS[k]} {sp:.2f} A": x for (k, sp), x in med.items()},
                          {f"{COLUMNS[k]} {sp:.2f} A": counts[(k, sp)] for (k, sp) in med},
                          fall, within, none_n / on_n if on_n else 0.0, v, why)
    if on_n and none_n / on_n > 0.05:
        notes.append(f"{100 * none_n / on_n:.0f} % of the commanded-on samples carry no current "
                     f"(relay not closing, a cut-off or the over-temperature cut): not read "
                     f"as a supply limit")
    return CurrentCheck(tuple(used), len(per_rec), fs, zero, lag, short, tuple(notes))


def describe(mc: dict, indent: str = "") -> list[str]:
    """Console lines of a check in its report form (``CurrentCheck.to_dict``): the diagnosis'
    log and the text report both print these."""
    if not mc["columns"]:
        return [f"{indent}measured currents: none usable ({'; '.join(mc['notes'])})"]
    out = [f"{indent}measured currents ({', '.join(mc['columns'])}, {mc['recordings']} recordings):"]
    g = mc["lag"]
    if g is not None:
        out.append(f"{indent}    lag after the command's edges: median {1000 * g['median_s']:.0f} ms "
                   f"(quartiles {1000 * g['q25_s']:.0f}-{1000 * g['q75_s']:.0f} ms, {g['edges']} "
                   f"edges; a delay from {1000 * g['threshold_s']:.0f} ms): actuation delay "
                   f"{g['verdict']}")
    else:
        out.append(f"{indent}    lag: no edge to time")
    s = mc["shortfall"]
    if s is not None:
        per: dict[str, list[str]] = {}
        for key, v in s["ratio_by_setpoint"].items():
            col, amps = key.split(" ", 1)
            per.setdefault(col, []).append(f"{v:.3f} at {amps}")
        ratios = "; ".join(f"{col} {', '.join(x)}" for col, x in per.items())
        out.append(f"{indent}    measured / commanded on the plateaus: {ratios}")
        out.append(f"{indent}    supply limit {s['verdict']}: {s['why']}")
    for n in mc["notes"]:
        out.append(f"{indent}    note: {n}")
    return out


@dataclass(frozen=True)
class HallSensor:
    """A Hall current sensor per channel as the generators write it: a gain and a zero per
    channel (fixed for the dataset), white noise, and a 10-bit ADC's step (ACS712-05B on an
    UNO: 185 mV/A, 4.9 mV per count)."""

    gain: tuple[float, float, float]
    zero_A: tuple[float, float, float]
    noise_A: float = 0.03
    lsb_A: float = 0.0264

    @classmethod
    def draw(cls, rng: np.random.Generator, gain_sd: float = 0.015,
             zero_sd_A: float = 0.05) -> "HallSensor":
        return cls(tuple(1.0 + rng.normal(0.0, gain_sd, 3)), tuple(rng.normal(0.0, zero_sd_A, 3)))

    def read(self, current_A: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The reading (n, 3) of the currents that flowed (n, 3), A."""
        current_A = np.asarray(current_A, float)
        raw = (current_A * np.asarray(self.gain) + np.asarray(self.zero_A)
               + rng.normal(0.0, self.noise_A, current_A.shape))
        return np.round(raw / self.lsb_A) * self.lsb_A

    def columns(self, current_A: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """{"i1_meas": ..., ...}: the reading as recording columns."""
        reading = self.read(current_A, rng)
        return {c: reading[:, k] for k, c in enumerate(COLUMNS)}


__all__: Sequence[str] = ("COLUMNS", "CurrentCheck", "Lag", "Shortfall", "check", "describe",
                          "HallSensor")
