"""The recording format of rig logs and any "real" data, in one place (specification:
``docs/recording-format.md``; this docstring summarizes it).

A **recording** is a CSV file with a header line. Required columns::

    t          s, strictly increasing
    i1,i2,i3   commanded current of muscle k, A (supply setpoint while relay k is commanded on,
               0 while off): what the host knows, not a measurement
    theta_deg  measured bending angle, deg (>= 0)
    phi_deg    measured bending-plane angle, deg, in [0, 360) (ill-defined when theta ~ 0)

Optional: ``T1,T2,T3`` (spring temperatures, deg C: any of them, one per fitted thermistor; an
empty or ``nan`` cell is a missing reading, e.g. an open or shorted sensor), ``roll_deg,pitch_deg``,
raw IMU columns, measured currents ``i1_meas..``. Unknown columns are kept (``Recording.extra``)
and ignored by the tools that do not know them.

A **dataset** is a folder of recordings (``*.csv``), in time order by file name (natural order:
``rec_2`` before ``rec_10``), with an optional ``meta.json`` holding ``ambient_C``,
``sample_hz``, ``muscle_azimuth_deg`` (three angles) and the springs' wire,
``spring_wire_diameter_m`` and ``spring_specific_heat_J_kgK``. Other files in the folder are ignored
(the synthetic generator writes its ground truth *outside* the folder).

Every reading error is a :class:`RecordingError` (a ``ValueError``) whose message names the
file and, where it applies, the line (the header is line 1); the units are checked where a
slip is common and silent (a current in mA, ``t`` in ms, ``meta.json``'s ``sample_hz`` against
the time stamps). A reader asked to
(``imu_gap_max_s``) fills short runs of missing ``theta_deg``/``phi_deg`` readings instead
(``fill_imu_gaps``).

:class:`RecordingWriter` appends rows and flushes them to the operating system at least once a
second (of wall time or of recorded time), so a crash loses at most the last second; the
hardware env records through it.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

REQUIRED_COLUMNS = ("t", "i1", "i2", "i3", "theta_deg", "phi_deg")
IMU_COLUMNS = ("theta_deg", "phi_deg")
TEMPERATURE_COLUMNS = ("T1", "T2", "T3")
META_KEYS = ("ambient_C", "sample_hz", "muscle_azimuth_deg", "spring_wire_diameter_m",
             "spring_specific_heat_J_kgK")
# What a rig builder can measure or read off the wire's datasheet, with the range a spring of
# 4-8 A can lie in; the bounds catch a value in the wrong unit (0.5 meant as mm).
WIRE_META_RANGES = {"spring_wire_diameter_m": (5e-5, 5e-3, "m, e.g. 0.0005 for 0.5 mm"),
                    "spring_specific_heat_J_kgK": (100.0, 2000.0, "J/(kg K), e.g. 837")}
META_FILE = "meta.json"
# The format's units where a slip is common and silent: an Arduino's millis() logged as t, a
# current logged in mA. Both make the diagnosis simulate nonsense for hours instead of failing.
# No SMA spring of this class takes 40 A (the paper's run at 4-8 A), and the neck
# moves within a second, so a log sparser than one sample a second is not one this tool reads.
MAX_CURRENT_A = 40.0
MAX_SAMPLE_INTERVAL_S = 1.0
# meta.json's sample_hz against the time stamps: a logger's jitter or a dropped sample moves the
# median interval by far less than this factor; a wrong unit or a wrong rate does not.
SAMPLE_HZ_TOLERANCE = 3.0


class RecordingError(ValueError):
    """A recording or dataset that cannot be read; the message names file and line."""

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        self.path = Path(path)
        self.line = line
        where = f"{self.path}" + (f", line {line}" if line is not None else "")
        super().__init__(f"{where}: {message}")


@dataclass
class Recording:
    """One recording: arrays of equal length n (one row per sample)."""

    t: np.ndarray  # (n,) s
    currents_A: np.ndarray  # (n, 3) commanded i1, i2, i3
    theta_deg: np.ndarray  # (n,)
    phi_deg: np.ndarray  # (n,) in [0, 360)
    # (n, 3) T1..T3 when any is recorded; NaN: a channel not recorded, or a missing reading
    temperatures_C: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # other columns, as floats or str
    name: str = ""
    path: Path | None = None
    # (n,) True where theta/phi were missing in the file and interpolated (``imu_gap_max_s``)
    imu_filled: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.t)
        self.t = np.asarray(self.t, float)
        self.currents_A = np.asarray(self.currents_A, float).reshape(n, 3)
        self.theta_deg = np.asarray(self.theta_deg, float)
        self.phi_deg = np.asarray(self.phi_deg, float)
        if self.temperatures_C is not None:
            self.temperatures_C = np.asarray(self.temperatures_C, float).reshape(n, 3)
        for name, arr in (("theta_deg", self.theta_deg), ("phi_deg", self.phi_deg)):
            if arr.shape != (n,):
                raise ValueError(f"{name} has shape {arr.shape}, expected ({n},)")

    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def i1(self) -> np.ndarray:
        return self.currents_A[:, 0]

    @property
    def i2(self) -> np.ndarray:
        return self.currents_A[:, 1]

    @property
    def i3(self) -> np.ndarray:
        return self.currents_A[:, 2]

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if self.n else 0.0

    def columns(self) -> dict[str, np.ndarray]:
        """All columns in file order: required, temperatures (if any), extra."""
        cols = {"t": self.t, "i1": self.currents_A[:, 0], "i2": self.currents_A[:, 1],
                "i3": self.currents_A[:, 2], "theta_deg": self.theta_deg, "phi_deg": self.phi_deg}
        if self.temperatures_C is not None:
            for k, name in enumerate(TEMPERATURE_COLUMNS):
                if np.isfinite(self.temperatures_C[:, k]).any():  # a channel never read: no column
                    cols[name] = self.temperatures_C[:, k]
        cols.update(self.extra)
        return cols


@dataclass
class Dataset:
    """A folder of recordings in time order, with its metadata."""

    recordings: list[Recording]
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    @property
    def has_temperatures(self) -> bool:
        """Any recording holds a spring temperature reading (any channel)."""
        return any(r.temperatures_C is not None and np.isfinite(r.temperatures_C).any()
                   for r in self.recordings)

    def __len__(self) -> int:
        return len(self.recordings)

    def __iter__(self):
        return iter(self.recordings)


# -- reading ------------------------------------------------------------------------------------

def _parse_float(text: str, path: Path, line: int, column: str, missing_ok: bool = False) -> float:
    """A finite number; with ``missing_ok`` (a thermistor column) an empty or NaN cell is a
    missing reading (NaN), while text or an infinity is still an error."""
    s = text.strip()
    if s == "":
        if missing_ok:
            return math.nan
        raise RecordingError(path, f"column {column!r} is empty (a NaN row)", line)
    try:
        v = float(s)
    except ValueError:
        raise RecordingError(path, f"column {column!r} is not a number: {s!r}", line) from None
    if math.isnan(v) and missing_ok:
        return math.nan
    if not math.isfinite(v):
        raise RecordingError(path, f"column {column!r} is {s!r} (a NaN row; values must be finite)",
                             line)
    return v


def read_recording(path: str | Path, imu_gap_max_s: float = 0.0) -> Recording:
    """Read and validate one recording CSV (see the module docstring for the format).

    ``imu_gap_max_s`` > 0: an empty or ``nan`` ``theta_deg``/``phi_deg`` cell is an IMU reading
    that did not arrive (a failed I2C read), filled from its neighbours when the gap between
    the readings around it lasts at most that long (``fill_imu_gaps``; at an end of the
    recording, the nearest reading is held as long); a longer gap is still an error. 0 (the
    default): every cell must hold a finite number."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise RecordingError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise RecordingError(path, f"not a text CSV file ({exc.reason})") from exc
    if not text.strip():
        raise RecordingError(path, "the file is empty (expected a header line and data rows)")
    reader = csv.reader(io.StringIO(text))
    header: list[str] | None = None
    line_no = 0
    rows: list[tuple[int, list[str]]] = []
    for row in reader:
        line_no = reader.line_num
        if not row or all(not c.strip() for c in row):
            continue  # blank lines are allowed anywhere
        if header is None:
            header = [c.strip() for c in row]
            header_line = line_no
            continue
        rows.append((line_no, row))
    assert header is not None
    dupes = sorted({c for c in header if header.count(c) > 1})
    if dupes:
        raise RecordingError(path, f"duplicate column(s) {', '.join(dupes)} in the header",
                             header_line)
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    sep = next((s for s in ";\t|" if len(header) == 1 and s in header[0]), None)
    if missing and sep:
        # a spreadsheet in a comma-decimal locale exports ';'
        raise RecordingError(path, f"the header is one field holding {sep!r}: the format is "
                                   f"comma-separated (export with ',' between the columns and "
                                   f"'.' as the decimal point)", header_line)
    if missing:
        raise RecordingError(path, f"missing required column(s) {', '.join(missing)} "
                                   f"(header has: {', '.join(header)}; required: "
                                   f"{', '.join(REQUIRED_COLUMNS)})", header_line)
    if not rows:
        raise RecordingError(path, "no data rows after the header (an empty recording)")
    idx = {c: header.index(c) for c in header}
    # a rig with thermistors on some springs only writes their columns
    t_cols = [c for c in TEMPERATURE_COLUMNS if c in idx]
    numeric = list(REQUIRED_COLUMNS) + t_cols
    extra_names = [c for c in header if c not in numeric]
    values = np.empty((len(rows), len(numeric)))
    extra_raw: dict[str, list[str]] = {c: [] for c in extra_names}
    n_req = len(REQUIRED_COLUMNS)
    imu_missing_ok = imu_gap_max_s > 0
    # per column, once: which may hold a missing reading
    missing_ok = [j >= n_req or (imu_missing_ok and c in IMU_COLUMNS) for j, c in enumerate(numeric)]
    for r, (ln, row) in enumerate(rows):
        if len(row) != len(header):
            raise RecordingError(path, f"{len(row)} fields, the header has {len(header)}", ln)
        for j, c in enumerate(numeric):
            values[r, j] = _parse_float(row[idx[c]], path, ln, c, missing_ok=missing_ok[j])
        for c in extra_names:
            extra_raw[c].append(row[idx[c]].strip())
    t = values[:, 0]
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise RecordingError(path, f"time t = {t[k]:.6g} s does not increase (previous row: "
                                   f"t = {t[k - 1]:.6g} s); t must be strictly increasing",
                             rows[k][0])
    cur = values[:, 1:4]
    neg = np.argwhere(cur < 0)
    if neg.size:
        r, k = neg[0]
        raise RecordingError(path, f"commanded current i{k + 1} = {cur[r, k]:g} A is negative",
                             rows[r][0])
    big = np.argwhere(cur > MAX_CURRENT_A)
    if big.size:
        r, k = big[0]
        raise RecordingError(path, current_unit_problem(f"i{k + 1}", float(cur[r, k])), rows[r][0])
    interval = sample_interval_problem(t)
    if interval:
        raise RecordingError(path, interval)
    theta = values[:, 4]
    neg = np.flatnonzero(theta < 0)
    if neg.size:
        raise RecordingError(path, f"theta_deg = {theta[neg[0]]:g} is negative", rows[neg[0]][0])
    phi = np.mod(values[:, 5], 360.0)
    filled = None
    if imu_missing_ok:
        theta, phi, filled = fill_imu_gaps(t, theta, phi, imu_gap_max_s, path,
                                           [ln for ln, _ in rows])
    temps = None
    if t_cols:
        temps = np.full((len(rows), 3), math.nan)
        for j, c in enumerate(t_cols):
            temps[:, TEMPERATURE_COLUMNS.index(c)] = values[:, n_req + j]
    extra: dict[str, np.ndarray] = {}
    for c, vals in extra_raw.items():
        try:
            extra[c] = np.array([float(v) if v else math.nan for v in vals])
        except ValueError:
            extra[c] = np.array(vals, dtype=object)
    return Recording(t=t, currents_A=cur, theta_deg=theta, phi_deg=phi, temperatures_C=temps,
                     extra=extra, name=path.stem, path=path, imu_filled=filled)


def current_unit_problem(column: str, value_A: float) -> str:
    """What is wrong with a commanded current above ``MAX_CURRENT_A`` (the message)."""
    return (f"commanded current {column} = {value_A:g} A is more than any SMA spring of this "
            f"class takes (the paper's run at 4-8 A; the format stops at {MAX_CURRENT_A:g} A): "
            f"currents are in amperes -- if this column is in milliamperes, divide it by 1000")


def median_interval_s(t: np.ndarray) -> float:
    """The median time between samples ``t`` (s); NaN for fewer than two."""
    return float(np.median(np.diff(t))) if t.size > 1 else math.nan


def sample_interval_problem(t: np.ndarray) -> str:
    """What is wrong with time stamps ``t`` (s) whose median interval exceeds
    ``MAX_SAMPLE_INTERVAL_S`` (the message; empty when nothing is)."""
    dt = median_interval_s(t)
    if not dt > MAX_SAMPLE_INTERVAL_S:
        return ""
    return (f"samples are a median {dt:g} s apart (t {t[0]:g} to {t[-1]:g}): t is in seconds and "
            f"the neck moves within one, so a rig logs at tens of Hz -- if t counts "
            f"milliseconds (an Arduino's millis()), divide it by 1000")


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in a boolean array, as (first, one past the last) index pairs."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def gap_span_s(t: np.ndarray, a: int, b: int) -> float:
    """How long rows a..b-1 go without a reading: from the reading before them to the one
    after, or at an end of the recording from its first or last row to the nearest reading
    (which is held there: the neck is at rest or moving slowly)."""
    return float(t[min(b, t.size - 1)] - t[max(a - 1, 0)])


def fill_imu_gaps(t: np.ndarray, theta_deg: np.ndarray, phi_deg: np.ndarray, max_gap_s: float,
                  path: str | Path = "", lines: Sequence[int] | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Missing (NaN) IMU readings filled from the readings around them.

    A row misses its reading when ``theta_deg`` or ``phi_deg`` is NaN. Each run of such rows is
    filled by interpolating the tilt vector (theta cos phi, theta sin phi) linearly in ``t``
    between the complete rows on either side -- the vector, not the angles, because phi wraps
    at 360 and is ill-defined near theta = 0 -- when those two rows are at most ``max_gap_s``
    apart: the neck moves a few degrees per second at most, so a dropout of a fraction of a
    second is a straight line well inside the sensor's noise. At either end of the recording
    the nearest reading is held, over no longer than ``max_gap_s`` either. Where only phi is
    missing, theta is kept as read. A longer run, or a recording with no reading at all, is a
    ``RecordingError`` naming its lines (``lines``: the file line of each row).

    Returns theta, phi (new arrays) and the (n,) mask of filled rows (None: nothing missing)."""
    gone = ~(np.isfinite(theta_deg) & np.isfinite(phi_deg))
    if not gone.any():
        return theta_deg, phi_deg, None
    lines = list(lines) if lines is not None else list(range(2, t.size + 2))
    theta, phi = theta_deg.copy(), phi_deg.copy()
    ok = ~gone
    for a, b in runs(gone):  # rows a..b-1 are missing
        where = (f"{'line ' + str(lines[a]) if b - a == 1 else f'lines {lines[a]}-{lines[b - 1]}'}"
                 f" ({b - a} row{'s' if b - a > 1 else ''})")
        if a == 0 and b == t.size:
            raise RecordingError(path, "theta_deg/phi_deg missing on every row: no IMU reading "
                                       "to fill them from")
        span = gap_span_s(t, a, b)
        if span > max_gap_s:
            side = (f" at the start of the recording: the first reading is {span:.3g} s away"
                    if a == 0 else
                    f" at the end of the recording: the last reading is {span:.3g} s away"
                    if b == t.size else f": the readings around them are {span:.3g} s apart")
            raise RecordingError(path, f"theta_deg/phi_deg missing on {where}{side}, more than "
                                       f"the {max_gap_s:g} s a dropout may be filled over", lines[a])
    th, ph = theta_deg[ok], np.radians(phi_deg[ok])
    xi = np.interp(t[gone], t[ok], th * np.cos(ph))
    yi = np.interp(t[gone], t[ok], th * np.sin(ph))
    keep_theta = np.isfinite(theta_deg[gone])
    theta[gone] = np.where(keep_theta, theta_deg[gone], np.hypot(xi, yi))
    p = np.mod(np.degrees(np.arctan2(yi, xi)), 360.0)
    phi[gone] = np.where(p >= 360.0, 0.0, p)  # mod of a tiny negative angle rounds to 360
    return theta, phi, gone


def _natural_key(p: Path):
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


def wire_meta_problem(key: str, value: Any) -> str | None:
    """What is wrong with a wire key of ``meta.json`` (None: absent or fine)."""
    if value is None:
        return None
    lo, hi, unit = WIRE_META_RANGES[key]
    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)):
        return f"{key} must be a finite number, got {value!r}"
    if not lo <= value <= hi:
        return f"{key} must lie in [{lo:g}, {hi:g}] ({unit}), got {value!r}"
    return None


def check_wire(wire: Mapping[str, float]) -> dict[str, float]:
    """``wire`` (meta.json's wire keys, SI units) as a dict; ValueError names an unknown key or
    a bad value."""
    unknown = sorted(set(wire) - set(WIRE_META_RANGES))
    if unknown:
        raise ValueError(f"unknown wire keys {unknown}; known: {sorted(WIRE_META_RANGES)}")
    for key, value in wire.items():
        problem = wire_meta_problem(key, value)
        if problem:
            raise ValueError(problem)
    return dict(wire)


# the springs' wire on a command line: (option, metavar, meta.json key, option unit in SI,
# unit, help)
_WIRE_OPTIONS = (
    ("--wire-diameter-mm", "MM", "spring_wire_diameter_m", 1e-3, "mm",
     "the springs' wire diameter, mm (meta.json's spring_wire_diameter_m): with "
     "--wire-specific-heat the diagnosis reports h in W/m^2K"),
    ("--wire-specific-heat", "J_KGK", "spring_specific_heat_J_kgK", 1.0, "J/(kg K)",
     "the wire's specific heat from its datasheet, J/(kg K) (meta.json's "
     "spring_specific_heat_J_kgK)"),
)


def _dest(option: str) -> str:
    """The argparse attribute of a wire option: given explicitly by add_wire_arguments and
    read by wire_from_arguments, so both use this one rule."""
    return option.lstrip("-").replace("-", "_")


def add_wire_arguments(ap: argparse.ArgumentParser) -> None:
    """The springs' wire on a command line (the rig's protocol, the diagnosis)."""
    for opt, metavar, *_, help_ in _WIRE_OPTIONS:
        ap.add_argument(opt, dest=_dest(opt), type=float, default=None, metavar=metavar,
                        help=help_)


def wire_from_arguments(args: argparse.Namespace) -> dict[str, float]:
    """meta.json's wire keys (SI units) from ``add_wire_arguments``' options, those given;
    ValueError names a bad one with its range in the option's unit."""
    wire = {}
    for opt, _metavar, key, scale, unit, _help in _WIRE_OPTIONS:
        value = getattr(args, _dest(opt))
        if value is None:
            continue
        if wire_meta_problem(key, value * scale):
            lo, hi, _ = WIRE_META_RANGES[key]
            raise ValueError(f"{opt} must lie in [{lo / scale:g}, {hi / scale:g}] {unit}, "
                             f"got {value!r}")
        wire[key] = value * scale
    return wire


def read_meta(path: str | Path) -> dict[str, Any]:
    """Read and validate a dataset's ``meta.json`` (all keys optional, unknown keys kept)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise RecordingError(path, f"not valid JSON ({exc.msg})", exc.lineno) from None
    if not isinstance(data, dict):
        raise RecordingError(path, "meta.json must hold a JSON object")
    for key in ("ambient_C", "sample_hz"):
        if key in data and data[key] is not None:
            v = data[key]
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
                raise RecordingError(path, f"{key} must be a finite number, got {v!r}")
    if "sample_hz" in data and data["sample_hz"] is not None and data["sample_hz"] <= 0:
        raise RecordingError(path, f"sample_hz must be > 0, got {data['sample_hz']!r}")
    if "ambient_C" in data and data["ambient_C"] is not None and not -40 <= data["ambient_C"] <= 60:
        raise RecordingError(path, f"ambient_C must lie in [-40, 60] C, got {data['ambient_C']!r}")
    for key in WIRE_META_RANGES:
        problem = wire_meta_problem(key, data.get(key))
        if problem:
            raise RecordingError(path, problem)
    az = data.get("muscle_azimuth_deg")
    if az is not None:
        if not (isinstance(az, list) and len(az) == 3 and all(
                isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a)
                for a in az)):
            raise RecordingError(path, f"muscle_azimuth_deg must be a list of three angles, "
                                       f"got {az!r}")
    return data


def read_dataset(directory: str | Path, imu_gap_max_s: float = 0.0) -> Dataset:
    """Read every ``*.csv`` of a folder in natural name order, and its optional ``meta.json``
    (``imu_gap_max_s``: ``read_recording``)."""
    directory = Path(directory)
    if not directory.exists():
        raise RecordingError(directory, "no such dataset folder")
    if not directory.is_dir():
        raise RecordingError(directory, "a dataset must be a folder of *.csv recordings")
    files = sorted((p for p in directory.iterdir() if p.suffix.lower() == ".csv" and p.is_file()),
                   key=_natural_key)
    if not files:
        raise RecordingError(directory, "no *.csv recordings in this folder")
    meta_path = directory / META_FILE
    meta = read_meta(meta_path) if meta_path.exists() else {}
    recs = [read_recording(f, imu_gap_max_s) for f in files]
    hz = meta.get("sample_hz")
    for f, r in zip(files, recs):
        dt = median_interval_s(r.t)
        if hz is None or math.isnan(dt):
            continue
        if not 1.0 / SAMPLE_HZ_TOLERANCE <= dt * hz <= SAMPLE_HZ_TOLERANCE:
            raise RecordingError(meta_path, f"sample_hz {hz:g} means samples 1/{hz:g} = "
                                            f"{1.0 / hz:.4g} s apart, but {f.name}'s are a median "
                                            f"{dt:.4g} s apart ({1.0 / dt:.4g} Hz): correct "
                                            f"sample_hz, or t if it is not in seconds")
    return Dataset(recs, meta, directory)


# -- writing ------------------------------------------------------------------------------------

def _fmt(v: Any) -> str:
    if isinstance(v, str):
        return v
    f = float(v)
    if not math.isfinite(f):
        return "nan"
    return repr(round(f, 9)) if abs(f) >= 1e-4 or f == 0 else f"{f:.9g}"


class RecordingWriter:
    """Append rows to a recording CSV as they come; flushed at least every ``flush_s`` seconds.

    ``columns`` must contain the required ones (``t, i1, i2, i3, theta_deg, phi_deg``); extra
    columns (``T1..T3``, raw IMU, ...) are written in the given order. Rows are dicts or
    keyword arguments; required values must be finite; a missing or NaN thermistor reading
    (``T1..T3``: an open or shorted sensor) and other missing extra values are written empty.
    The writer validates what
    :func:`read_recording` would reject (missing required value, NaN, t not increasing, a
    current over ``MAX_CURRENT_A``) and raises ``ValueError`` before writing a bad row, so what
    is on disk always reads back -- logged at least once a second (``MAX_SAMPLE_INTERVAL_S``:
    the median interval, which no single row decides).

    The file is flushed to the operating system whenever ``flush_s`` of wall time or of
    recorded time has passed since the last flush (and on ``close``), so a crash of the
    process loses at most that much; ``fsync=True`` also forces it to the disk.
    """

    def __init__(self, path: str | Path, columns: Sequence[str] = REQUIRED_COLUMNS,
                 flush_s: float = 0.5, fsync: bool = False):
        self.path = Path(path)
        cols = [str(c).strip() for c in columns]
        missing = [c for c in REQUIRED_COLUMNS if c not in cols]
        if missing:
            raise ValueError(f"RecordingWriter({self.path}): missing required column(s) "
                             f"{', '.join(missing)}")
        if len(set(cols)) != len(cols):
            raise ValueError(f"RecordingWriter({self.path}): duplicate columns in {cols}")
        if not (flush_s >= 0 and math.isfinite(flush_s)):
            raise ValueError(f"flush_s must be >= 0, got {flush_s!r}")
        self.columns = tuple(cols)
        # required columns must be finite in every row (the reader rejects NaN rows there);
        # a thermistor that drops out mid-recording must not end it: its cell is left empty
        self._strict = [c for c in cols if c in REQUIRED_COLUMNS]
        self.flush_s = float(flush_s)
        self.fsync = fsync
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "w", encoding="utf-8", newline="")
        self._f.write(",".join(self.columns) + "\n")
        self._last_t = -math.inf
        self._flush_wall = time.monotonic()
        self._flush_t: float | None = None
        self.rows = 0
        self._flush()

    def write(self, row: Mapping[str, Any] | None = None, **values: Any) -> None:
        """Append one row (mapping and/or keywords of column -> value)."""
        if self._f.closed:
            raise ValueError(f"{self.path}: writer is closed")
        data = dict(row or {})
        data.update(values)
        unknown = set(data) - set(self.columns)
        if unknown:
            raise ValueError(f"{self.path}: unknown column(s) {sorted(unknown)}; "
                             f"columns are {list(self.columns)}")
        for c in self._strict:
            v = data.get(c)
            if v is None or not math.isfinite(float(v)):
                raise ValueError(f"{self.path}: row {self.rows + 1} needs a finite {c}, got {v!r}")
        t = float(data["t"])
        if t <= self._last_t:
            raise ValueError(f"{self.path}: t = {t} s does not increase (previous {self._last_t} s)")
        for k in ("i1", "i2", "i3", "theta_deg"):
            if float(data[k]) < 0:
                raise ValueError(f"{self.path}: {k} = {data[k]} must be >= 0")
            if k != "theta_deg" and float(data[k]) > MAX_CURRENT_A:
                raise ValueError(f"{self.path}: row {self.rows + 1}: "
                                 f"{current_unit_problem(k, float(data[k]))}")
        for c in TEMPERATURE_COLUMNS:
            v = data.get(c)
            if v is not None and not isinstance(v, str) and math.isinf(float(v)):
                raise ValueError(f"{self.path}: row {self.rows + 1}: {c} = {v!r} is infinite "
                                 f"(write a missing reading as NaN or None)")
            if v is not None and not isinstance(v, str) and math.isnan(float(v)):
                data[c] = None
        data["phi_deg"] = float(data["phi_deg"]) % 360.0
        self._f.write(",".join("" if data.get(c) is None else _fmt(data[c])
                               for c in self.columns) + "\n")
        self._last_t = t
        self.rows += 1
        if self._flush_t is None:
            self._flush_t = t
        now = time.monotonic()
        if now - self._flush_wall >= self.flush_s or t - self._flush_t >= self.flush_s:
            self._flush(t)

    def write_many(self, rows: Iterable[Mapping[str, Any]]) -> None:
        for r in rows:
            self.write(r)

    def _flush(self, t: float | None = None) -> None:
        self._f.flush()
        if self.fsync:
            os.fsync(self._f.fileno())
        self._flush_wall = time.monotonic()
        self._flush_t = t

    def flush(self) -> None:
        if not self._f.closed:
            self._flush(self._last_t if self.rows else None)

    def close(self) -> None:
        if not self._f.closed:
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()

    @property
    def closed(self) -> bool:
        return self._f.closed

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_recording(path: str | Path, recording: Recording | Mapping[str, Sequence[float]]) -> Path:
    """Write a whole recording (a :class:`Recording` or a mapping column -> values) as CSV.

    Validated like :class:`RecordingWriter` rows (required columns, finite, t increasing)."""
    path = Path(path)
    cols = recording.columns() if isinstance(recording, Recording) else dict(recording)
    names = [str(c) for c in cols]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise ValueError(f"{path}: missing required column(s) {', '.join(missing)}")
    arrays = [np.atleast_1d(np.asarray(cols[c])) for c in cols]
    lengths = {a.shape[0] for a in arrays}
    if len(lengths) != 1:
        raise ValueError(f"{path}: columns have different lengths {sorted(lengths)}")
    req = {c: np.asarray(cols[c], float) for c in REQUIRED_COLUMNS}
    for c, a in req.items():
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{path}: column {c} has non-finite values")
    if np.any(np.diff(req["t"]) <= 0):
        raise ValueError(f"{path}: t must be strictly increasing")
    for c in ("i1", "i2", "i3", "theta_deg"):
        if np.any(req[c] < 0):
            raise ValueError(f"{path}: {c} must be >= 0")
        if c != "theta_deg" and np.any(req[c] > MAX_CURRENT_A):
            raise ValueError(f"{path}: {current_unit_problem(c, float(req[c].max()))}")
    interval = sample_interval_problem(req["t"])
    if interval:
        raise ValueError(f"{path}: {interval}")
    for c in TEMPERATURE_COLUMNS:
        if c in names and np.any(np.isinf(np.asarray(cols[c], float))):
            raise ValueError(f"{path}: column {c} has infinite values (a missing reading is NaN)")
    arrays[names.index("phi_deg")] = np.mod(req["phi_deg"], 360.0)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [",".join(names)]
    for i in range(lengths.pop()):
        lines.append(",".join("" if c in TEMPERATURE_COLUMNS and not np.isfinite(a[i])
                              else _fmt(a[i]) for c, a in zip(names, arrays)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_meta(directory: str | Path, meta: Mapping[str, Any]) -> Path:
    """Write a dataset's ``meta.json``."""
    p = Path(directory) / META_FILE
    p.write_text(json.dumps(dict(meta), indent=2) + "\n")
    return p
