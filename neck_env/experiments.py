"""The recording protocol the sim-to-real diagnosis expects: one definition for every user of it.

The synthetic generators (``neck_env.gap.synthetic``, ``neck_env.gap.independent``), the rig's
``python -m neck_env.rig protocol`` and ``docs/gap.md`` all take their experiments from here, so
what a user records on the bench is what the diagnosis was checked on.

A protocol is a list of :class:`Recording`: each a relay schedule at **one** supply current (the
rig switches a bench supply through relays, so a recording never needs two current levels), a
duration, and the rest it must start from. What each kind of recording pins down:

=================  ======================================================================  ==========================
kind               what is run                                                             what it identifies
=================  ======================================================================  ==========================
``pulse``          one muscle on for 5 s from t = 2 s, then cooling to the end (the        onset timing (A_s'), the
                   paper's Table 1 / Fig. 7 experiment) at 4-8 A, every muscle             current sweep (C_A, gamma_L),
                                                                                           per-muscle differences
``sequence``       relays switched every 2-3.5 s among single muscles and pairs for         coupling of muscles,
                   ~14 s at one supply current, then cooling                               antagonist pre-warming, phi
``cycles``         one muscle 3 s on / 4 s off, three times                                 history (partial-transformation
                                                                                           memory), fatigue, creep
``long_cool``      one muscle at 7 A for 5 s, then a 55 s cooling tail                      convection h (and whether h
                                                                                           depends on temperature)
``reference``      muscle 1 at 7 A for 5 s from t = 2 s, first in the session: the same    what changed with use, with
                   input as the first 30 s of muscle 1's ``long_cool`` near its end        no model (``gap.repeats``):
                                                                                           fatigue, a draft, a drift
=================  ======================================================================  ==========================

Protocols:

* ``mixed`` (default, 15 x 30 s): 9 pulses, 3 sequences, 3 cycle recordings, shuffled with the
  seed (the order matters only for effects that build up over use).
* ``paper``: the paper's own 5 s pulses (4-5 A of its Fig. 7, 6-8 A of its Table 1).
* ``rig``: a ``reference`` pulse, ``mixed``, then two ``long_cool`` recordings (60 s): what the
  rig should record. The long tails separate a draft or a temperature-dependent h from a plain
  recalibration of h; the reference and muscle 1's long tail give the same input at the
  session's start and end, so a loss of actuation with use (fatigue) shows against no model.
* ``drawn``: the same kinds with another lab's timing, drawn per recording: pulses from
  t = 0.5-4 s held 2.5-9 s at any current in 4-8 A (0.1 A steps), relay sequences of 1-5 s
  segments at 4.5-7.5 A, 2-4 cycles of 1.5-4 s on and 2-8 s off, and at least 8 s of cooling.
  Not a protocol to record by: it checks that the diagnosis does not lean on this module's
  pulse timing (``benchmarks/gap_blind.py --protocol drawn``).

Every recording must start **at rest**: upright (tilt back at its rest reading) with the springs
at ambient. ``REST`` says how close is close enough (``Recording.rest``: the ``reference`` and
``long_cool`` recordings start with the springs within ``REPEAT_START_K`` of ambient, not 3 K,
so a repeat starts where its first did); the rig waits for it, the diagnosis checks it.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

__all__ = ["Recording", "RestCriterion", "REST", "REPEAT_START_K", "PROTOCOLS",
           "RECORDING_PROTOCOLS", "diagnosis_protocol", "protocol_schedule", "truth_path_for",
           "add_dataset_arguments", "dataset_arguments"]

RECORDING_PROTOCOLS = ("mixed", "paper", "rig")  # what a rig records (the rig CLI offers these)
PROTOCOLS = (*RECORDING_PROTOCOLS, "drawn")  # and the generators' check of the timing
PULSE_START_S = 2.0
PULSE_ON_S = 5.0
REFERENCE_A = 7.0  # the rig protocol's reference pulse and long cooling tails (muscle 1, 2)


@dataclass(frozen=True)
class RestCriterion:
    """When a neck counts as at rest, before a recording starts."""

    tilt_deg: float = 0.6  # tilt within this of the rest (upright) reading
    temperature_K: float = 3.0  # every spring within this of ambient
    settle_s: float = 3.0  # ... held for this long (the filter and a slow creep settle)
    timeout_s: float = 900.0  # give up waiting after this (a hot neck is a fault)
    # A neck whose springs are cold but which stays off its rest reading without moving is held
    # there by its backbone (stiction: ``backbone_friction``'s dead band, up to ~2 deg at the
    # catalogue's 0.05 N m): no wait brings it back. Not moving: its tilt stays within
    # ``steady_deg`` (a few times the fused tilt's noise) of where it settled for ``stuck_s``,
    # twice creep's longest time constant (10 s), so a neck still creeping back is not taken
    # for a stuck one.
    steady_deg: float = 0.15
    stuck_s: float = 20.0
    # The ambient a rig was given may be off by a kelvin or two (a guess, a room that warmed):
    # a spring that stopped cooling (the hottest fell by under ``plateau_K`` over the last
    # ``plateau_s``) within ``plateau_within_K`` of it counts as at ambient. Moot at
    # ``temperature_K`` = 3 K; it keeps a tighter start (``Recording.start_within_K``) from
    # waiting forever on a wrong ambient.
    plateau_within_K: float = 3.0
    # 0.05 K in 20 s: a spring 1 K over its ambient still cools faster than that for any
    # time constant under 6.5 min (excess x (1 - exp(-20 s / tau)))
    plateau_K: float = 0.05
    plateau_s: float = 20.0

    def springs_cold(self, times_s: Sequence[float], excess_K: Sequence[float]) -> bool:
        """Are the springs at ambient, given the hottest spring's excess over ambient (K) read
        at ``times_s`` (s, increasing; the last is now)? Within ``temperature_K``, or no
        longer cooling within ``plateau_within_K`` (2 s means at both ends of the window damp
        a thermistor's noise)."""
        t, e = np.asarray(times_s, float), np.asarray(excess_K, float)
        if e.size == 0:
            return False
        if e[-1] <= self.temperature_K:
            return True
        if e[-1] > self.plateau_within_K or t[-1] - t[0] < self.plateau_s:
            return False
        start = t[-1] - self.plateau_s
        old = e[(t <= start) & (t >= start - 2.0)]
        new = e[t >= t[-1] - 2.0]
        return bool(old.size and old.mean() - new.mean() < self.plateau_K)


REST = RestCriterion()
# A recording whose input another repeats (the rig protocol's ``reference`` and ``long_cool``)
# starts colder than REST.temperature_K: the emulated rig's wait at 3 K left its springs 3-4 K
# over ambient, and the reference's repeat bent 2.6 % more than the cold-started reference
# (a warmer spring transforms sooner), against the 3 % ``gap.repeats`` calls a loss.
REPEAT_START_K = 1.0


def simulated_wait(advance: Callable[[float], float], hottest_excess_K: Callable[[], float],
                   chunk_s: float = 1.0, criterion: RestCriterion = REST) -> float:
    """The rig protocol's wait between recordings, for a simulated plant with its relays off:
    ``advance(seconds)`` (returns the seconds it simulated) in chunks of ``chunk_s`` until
    ``hottest_excess_K()`` (the warmest spring over ambient) says the springs are cold
    (``criterion.springs_cold``; at most ``criterion.timeout_s``), then ``criterion.stuck_s``
    more -- the longest the rig waits before it records from a neck held where it stopped.
    Returns the seconds waited. The generators' ``starts="cooled"`` share it."""
    waited = 0.0
    times, excess = [0.0], [hottest_excess_K()]
    while waited < criterion.timeout_s and not criterion.springs_cold(times, excess):
        waited += advance(chunk_s)
        times.append(waited)
        excess.append(hottest_excess_K())
    return waited + advance(criterion.stuck_s)


@dataclass(frozen=True)
class Recording:
    """One recording of a protocol: relay segments at one supply current.

    ``segments`` are ``(t_on_s, t_off_s, muscles)`` with 0-based muscle indices; a relay is on
    for ``t_on_s <= t < t_off_s``. ``name`` is stable across runs (the rig resumes by it)."""

    name: str
    kind: str
    description: str
    supply_A: float
    duration_s: float
    segments: tuple[tuple[float, float, tuple[int, ...]], ...] = field(default_factory=tuple)
    start_within_K: float = REST.temperature_K  # the springs' start: within this of ambient

    @property
    def rest(self) -> RestCriterion:
        """The rest this recording must start from (``REST``, with its own temperature)."""
        return replace(REST, temperature_K=self.start_within_K)

    def sample_times(self, sample_hz: float) -> np.ndarray:
        """The recording's sample times (s) at ``sample_hz``: from 0 to its duration inclusive."""
        return np.arange(int(round(self.duration_s * sample_hz)) + 1) / sample_hz

    def currents(self, t_s: np.ndarray) -> np.ndarray:
        """Commanded currents (n, 3) at times ``t_s`` (A; the supply while a relay is on)."""
        t = np.asarray(t_s, dtype=float)
        cur = np.zeros((t.shape[0], 3))
        for t_on, t_off, muscles in self.segments:
            sel = (t >= t_on - 1e-9) & (t < t_off - 1e-9)
            for m in muscles:
                cur[sel, m] = self.supply_A
        return cur

    def relays_at(self, t_s: float) -> tuple[bool, bool, bool]:
        """Which relays are commanded on at time ``t_s``."""
        on = [False, False, False]
        for t_on, t_off, muscles in self.segments:
            if t_on - 1e-9 <= t_s < t_off - 1e-9:
                for m in muscles:
                    on[m] = True
        return tuple(on)  # type: ignore[return-value]

    @property
    def on_time_s(self) -> np.ndarray:
        """Total commanded on-time of each muscle (s)."""
        out = np.zeros(3)
        for t_on, t_off, muscles in self.segments:
            for m in muscles:
                out[m] += t_off - t_on
        return out

    @property
    def longest_on_s(self) -> float:
        """Longest continuous on-time of any relay (s): what the firmware's on-time cap sees."""
        best = 0.0
        for m in range(3):
            spans = sorted((a, b) for a, b, ms in self.segments if m in ms)
            run_start, run_end = None, None
            for a, b in spans:
                if run_end is not None and a <= run_end + 1e-9:
                    run_end = max(run_end, b)
                else:
                    run_start, run_end = a, b
                best = max(best, run_end - run_start)
        return best


# the relay states a sequence switches among: single muscles, neighbouring pairs, all off
SEQUENCE_STATES = ((0,), (1,), (2,), (0, 1), (1, 2), (0, 2), ())


def _kinds(n_recordings: int) -> list[str]:
    """The kinds of a mixed (or drawn) protocol's recordings, unshuffled: 60 % pulses (at least
    one), 20 % sequences, the rest cycles."""
    n_pulse = max(1, round(n_recordings * 0.6))
    n_seq = max(0, round(n_recordings * 0.2))
    return ["pulse"] * n_pulse + ["seq"] * n_seq + ["cycle"] * max(0, n_recordings - n_pulse - n_seq)


def _pulse(name: str, muscle: int, amps: float, duration_s: float, on_s: float = PULSE_ON_S,
           kind: str = "pulse", start_s: float = PULSE_START_S,
           start_within_K: float = REST.temperature_K) -> Recording:
    seg = ((start_s, start_s + on_s, (muscle,)),)
    return Recording(name, kind, f"pulse m{muscle + 1} {amps:g} A {on_s:g} s", float(amps),
                     float(duration_s), seg, start_within_K)


def diagnosis_protocol(seed: int | np.random.Generator = 0, protocol: str = "mixed",
                       n_recordings: int = 15, duration_s: float = 30.0) -> list[Recording]:
    """The protocol's recordings, in recording order (the seed shuffles and draws levels)."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; known: {PROTOCOLS}")
    if n_recordings < 1 or not duration_s > PULSE_START_S + PULSE_ON_S:
        raise ValueError(f"a protocol needs >= 1 recording longer than "
                         f"{PULSE_START_S + PULSE_ON_S:g} s (got {n_recordings}, {duration_s} s)")
    out: list[Recording] = []
    width = max(2, len(str(n_recordings + (3 if protocol == "rig" else 0))))
    nm = lambda: f"rec_{len(out) + 1:0{width}d}"
    if protocol == "rig":
        # the same input as the first 30 s of its long_cool on muscle 1: the session opens and
        # closes with it, so what changed with use shows without a model (gap.repeats)
        out.append(_pulse(nm(), 0, REFERENCE_A, duration_s, kind="reference",
                          start_within_K=REPEAT_START_K))
    if protocol == "paper":
        amps = [4.0, 4.25, 4.5, 4.75, 5.0, 6.0, 7.0, 8.0]
        combos = [(m, a) for a in amps for m in range(3)]
        idx = np.sort(rng.choice(len(combos), size=min(n_recordings, len(combos)), replace=False))
        for k in idx:
            m, a = combos[k]
            out.append(_pulse(nm(), m, a, duration_s))
        return out
    if protocol == "drawn":
        return _drawn(rng, n_recordings, duration_s, nm, out)
    # The draws below keep their order: a seed gives the same datasets as earlier versions.
    kinds = _kinds(n_recordings)
    n_pulse = kinds.count("pulse")
    kinds = list(rng.permutation(kinds))
    levels = np.linspace(4.0, 8.0, n_pulse) if n_pulse > 1 else np.array([6.0])
    levels = rng.permutation(levels)
    muscles = rng.permutation(np.arange(n_pulse) % 3)
    ip = 0
    for kind in kinds:
        if kind == "pulse":
            m, a = int(muscles[ip]), float(round(levels[ip] * 4) / 4)
            ip += 1
            out.append(_pulse(nm(), m, a, duration_s))
        elif kind == "seq":
            supply = float(rng.choice([5.5, 6.0, 6.5, 7.0]))
            on_time = np.zeros(3)
            tk = 2.0
            segs, desc = [], []
            while tk < 16.0:
                d = float(rng.uniform(2.0, 3.5))
                st = SEQUENCE_STATES[int(rng.integers(len(SEQUENCE_STATES)))]
                st = tuple(k for k in st if on_time[k] + d <= 7.0)
                if st:
                    segs.append((tk, tk + d, st))
                for k in st:
                    on_time[k] += d
                desc.append("".join(str(k + 1) for k in st) or "-")
                tk += d
            out.append(Recording(nm(), "sequence", f"relay sequence {supply:g} A [{' '.join(desc)}]",
                                 supply, float(duration_s), tuple(segs)))
        else:
            m = int(rng.integers(3))
            a = float(rng.choice([5.0, 5.5, 6.0]))
            segs = tuple((2.0 + 7.0 * c, 5.0 + 7.0 * c, (m,)) for c in range(3))
            out.append(Recording(nm(), "cycles", f"cycles m{m + 1} {a:g} A 3 s on / 4 s off x3",
                                 a, float(duration_s), segs))
    if protocol == "rig":
        for m in (0, 1):
            # both tails start cold: muscle 1's repeats the reference, and a tail fits h from
            # a start the model takes at ambient
            out.append(_pulse(nm(), m, REFERENCE_A, max(60.0, duration_s), kind="long_cool",
                              start_within_K=REPEAT_START_K))
    return out


DRAWN_MIN_COOL_S = 8.0  # every drawn recording ends with at least this much cooling
DRAWN_MAX_ON_S = 9.0  # under the firmware's 10 s on-time cap
DRAWN_START_S = (0.5, 4.0)  # the first relay closes in this window
DRAWN_MIN_PULSE_S = 2.5


def _down_to_cs(x: float) -> float:
    """x rounded down to 10 ms: a drawn time never passes the limit it was drawn under."""
    return float(np.floor(x * 100) / 100)


def _drawn(rng: np.random.Generator, n_recordings: int, duration_s: float, nm,
           out: list[Recording]) -> list[Recording]:
    """``drawn``: the mixed protocol's kinds and shares with timing and levels drawn wide."""
    budget = duration_s - DRAWN_MIN_COOL_S  # the last relay opens by then
    first, last = DRAWN_START_S
    if budget < first + DRAWN_MIN_PULSE_S:
        raise ValueError(f"the drawn protocol needs recordings of at least "
                         f"{first + DRAWN_MIN_PULSE_S + DRAWN_MIN_COOL_S:g} s (got {duration_s} s)")
    kinds = _kinds(n_recordings)
    muscles = rng.permutation(np.arange(kinds.count("pulse")) % 3)
    ip = 0
    for kind in rng.permutation(kinds):
        start = _down_to_cs(rng.uniform(first, min(last, budget - DRAWN_MIN_PULSE_S)))
        if kind == "pulse":
            on = _down_to_cs(rng.uniform(DRAWN_MIN_PULSE_S, min(DRAWN_MAX_ON_S, budget - start)))
            amps = float(round(rng.uniform(4.0, 8.0), 1))
            m = int(muscles[ip])
            ip += 1
            out.append(_pulse(nm(), m, amps, duration_s, on_s=on, start_s=start))
        elif kind == "seq":
            supply = float(round(rng.uniform(4.5, 7.5), 1))
            on_time, segs, desc, tk = np.zeros(3), [], [], start
            while True:
                d = float(round(rng.uniform(1.0, 5.0), 2))
                if tk + d > budget:
                    break
                st = tuple(k for k in SEQUENCE_STATES[int(rng.integers(len(SEQUENCE_STATES)))]
                           if on_time[k] + d <= DRAWN_MAX_ON_S)
                if st:
                    segs.append((tk, tk + d, st))
                on_time[list(st)] += d
                desc.append("".join(str(k + 1) for k in st) or "-")
                tk += d
            if not segs:  # a recording too short for a segment still heats one muscle
                segs.append((start, start + DRAWN_MIN_PULSE_S, (int(rng.integers(3)),)))
                desc.append(str(segs[0][2][0] + 1))
            out.append(Recording(nm(), "sequence", f"relay sequence {supply:g} A [{' '.join(desc)}]",
                                 supply, float(duration_s), tuple(segs)))
        else:
            m = int(rng.integers(3))
            amps = float(round(rng.uniform(4.5, 7.0), 1))
            on = _down_to_cs(rng.uniform(1.5, min(4.0, budget - start)))
            off = float(round(rng.uniform(2.0, 8.0), 2))
            n = int(min(rng.integers(2, 5), max(1, (budget - start + off) // (on + off)),
                        DRAWN_MAX_ON_S // on))
            segs = tuple((start + (on + off) * c, start + (on + off) * c + on, (m,)) for c in range(n))
            out.append(Recording(nm(), "cycles", f"cycles m{m + 1} {amps:g} A {on:g} s on / {off:g} "
                                 f"s off x{n}", amps, float(duration_s), segs))
    return out


def protocol_schedule(rng: np.random.Generator, protocol: str = "mixed", n_recordings: int = 15,
                      duration_s: float = 30.0, sample_hz: float = 50.0) -> list[tuple[str, np.ndarray]]:
    """[(description, commanded currents (n, 3) at the sample times)] in recording order."""
    out = []
    for rec in diagnosis_protocol(rng, protocol, n_recordings, duration_s):
        out.append((rec.description, rec.currents(rec.sample_times(sample_hz))))
    return out


# -- what every dataset generator's command line shares ------------------------------------------

def truth_path_for(out_dir: str | Path) -> Path:
    """Where a generator writes the truth of a dataset folder: beside it, never inside."""
    out_dir = Path(out_dir).resolve()
    return out_dir.parent / f"{out_dir.name}.truth.json"


def add_dataset_arguments(ap: argparse.ArgumentParser, effect_names: Sequence[str]) -> None:
    """The options of a synthetic dataset: effects, seed, protocol, size, temperatures, truth."""
    ap.add_argument("--effects", default="", help="comma-separated effect names (none: empty); "
                    f"known: {', '.join(effect_names)}")
    ap.add_argument("--effect-params", default=None,
                    help='JSON mapping name -> parameters fixing magnitudes, e.g. '
                         '\'{"imu_misalignment": {"yaw_deg": 8}}\'')
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--protocol", choices=PROTOCOLS, default="mixed")
    ap.add_argument("--recordings", type=int, default=15)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per recording")
    ap.add_argument("--sample-hz", type=float, default=50.0)
    tg = ap.add_mutually_exclusive_group()
    tg.add_argument("--temperatures", dest="temperatures", action="store_true", default=None)
    tg.add_argument("--no-temperatures", dest="temperatures", action="store_false")
    ap.add_argument("--truth", default=None, help="truth JSON path (default: OUT_DIR.truth.json "
                    "beside the folder)")
    ap.add_argument("--no-wire-meta", dest="wire_meta", action="store_false",
                    help="leave the wire's diameter and specific heat out of meta.json")
    ap.add_argument("--current-sensor", action="store_true",
                    help="also write i1_meas..i3_meas: a Hall sensor's reading of the current "
                         "that flowed")


def dataset_arguments(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """(effects: names or a name -> parameters mapping, the generator's keyword arguments) from
    ``add_dataset_arguments``' options; ValueError / JSONDecodeError name a bad one."""
    effects: Any = [e.strip() for e in args.effects.split(",") if e.strip() and e.strip() != "none"]
    if args.effect_params:
        mapping = {e: {} for e in effects}
        mapping.update(json.loads(args.effect_params))
        effects = mapping
    if args.recordings < 1 or args.duration <= 0 or args.sample_hz <= 0:
        raise ValueError("--recordings, --duration and --sample-hz must be positive")
    return effects, dict(seed=args.seed, protocol=args.protocol, n_recordings=args.recordings,
                         duration_s=args.duration, sample_hz=args.sample_hz,
                         temperatures=args.temperatures, truth_path=args.truth,
                         wire_meta=args.wire_meta, current_sensor=args.current_sensor)
