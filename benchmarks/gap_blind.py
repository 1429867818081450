"""Blind evaluation of the sim-to-real gap diagnosis (issue #6).

    python benchmarks/gap_blind.py                 # 43 datasets, ~1 h (30-160 s each, one at a time)
    python benchmarks/gap_blind.py --quick         # 15 datasets, ~20 min
    python benchmarks/gap_blind.py --hard          # rigs further from the model
    python benchmarks/gap_blind.py --out runs/gap_blind --resume   # skip datasets already done
    python benchmarks/gap_blind.py --ray auto      # datasets as Ray tasks on a cluster
    python benchmarks/gap_blind.py --generator independent --baseline wide --thermistors always
    python benchmarks/gap_blind.py --generator independent --baseline wide --first-seed 5000  # fresh rigs
    python benchmarks/gap_blind.py --generator third --baseline wide   # a third rig, written apart
    python benchmarks/gap_blind.py --protocol rig  # another recording protocol (neck_env.experiments)
    python benchmarks/gap_blind.py --generator independent --baseline wide --protocol drawn  # another lab's timing
    python benchmarks/gap_blind.py --generator independent --baseline wide --sample-hz 20  # another logger
    python benchmarks/gap_blind.py --generator independent --baseline wide --thermistors never --no-meta  # the tilt and currents only
    python benchmarks/gap_blind.py --generator independent --baseline wide --first-seed 7000 \
        --effect-free 30   # the false-positive rate alone, on 30 fresh effect-free rigs
    python benchmarks/gap_blind.py --summarize runs/a runs/b   # pool finished runs, print only
    python benchmarks/gap_blind.py --compare runs/mixed runs/rig   # the same seeds, paired

Each case is a synthetic dataset (``neck_env.gap.synthetic``, seeded; effect magnitudes drawn
uniformly in the catalogue ranges) diagnosed by the CLI exactly as a user runs it
(``neck_env.gap.cli.main([... '--json', ...])``); the tool sees the folder only, its truth is
written beside the folder and read here afterwards. Suite: effect-free datasets, every
catalogued effect alone (three magnitudes each), random pairs, and the out-of-catalogue
``gyro_bias_drift``.

Printed: top-1 identification rate of single effects, the rate of the true effect ranked
first *and* in the verdict (issue 11's scoring; targets: own generator >= 85 % with the wide
baseline, independent rig >= 80 %; top-1 >= 90 % with the default baseline), pairs with both effects
found (targets: own >= 70 %, independent >= 60 %), the single-effect score split by how much the effect moves the tilt
in the data (its RMS against a twin dataset with the effects off: same rig, protocol and noise;
the tool's own 0.3 deg bar between), false positives on effect-free data (target <= 10 %), the median
held-out gap reduction once the true effect is added (target >= 60 %), the confusion between
effects (which effect comes second and how much of the gap it also removes), and whether
gyro_bias_drift data come out "unexplained" with the residual localized in the tilt signals,
not concentrated in one phase, at rest as much as while heating. Every rate carries its exact
(Clopper-Pearson) 95 % interval: a suite's six effect-free rigs bound a false-positive rate
only to 0-46 %, so ``--effect-free N`` runs that many effect-free rigs alone.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import itertools
import json
import math
import shutil
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.stats import binomtest

from agents.distributed import add_ray_argument, fan_out
from neck_env import effects as fx
from neck_env.experiments import PROTOCOLS
from neck_env.gap.cli import main as gap_main
from neck_env.gap.independent import CONVECTION_LAWS
from neck_env.gap.model import tilt_vec
from neck_env.gap.synthetic import generate
from neck_env.recording import read_recording

# Why effects can be confused (the physics behind the runner-up table).
WHY = {
    frozenset({"convection_change", "thermal_coupling"}):
        "both change how fast a heated spring loses heat: coupling drains it into the "
        "neighbours like extra convection; only the neighbours' warming (temperatures, "
        "pre-warmed antagonists in multi-muscle runs) tells them apart",
    frozenset({"actuation_delay", "backbone_viscoelasticity"}):
        "both make the tilt lag the command: a pure delay shifts every edge, a Maxwell branch "
        "creeps; they differ at the start of heating (delay: flat; creep: fast then slow)",
    frozenset({"backbone_friction", "backbone_viscoelasticity"}):
        "both hold the head back on the return: friction leaves a residual tilt and a dead "
        "band, viscoelasticity a slow creep back",
    frozenset({"supply_limit", "convection_change"}):
        "both reduce the temperature rise at high currents; the supply limit acts only above "
        "V / R while heating, convection also while cooling",
    frozenset({"head_payload", "backbone_viscoelasticity"}):
        "both change the effective stiffness of the backbone; payload grows with theta",
    frozenset({"backbone_viscoelasticity", "supply_limit"}):
        "both make the bend at high currents smaller than the nominal model predicts from the "
        "commanded current; the Maxwell branch also slows the return, the supply limit leaves "
        "low currents and cooling untouched",
    frozenset({"imu_misalignment", "gyro_bias_drift"}):
        "both offset the reading; misalignment is constant, drift grows with time",
}


FIRST_SEED = 1000  # the development suite (the current figures are on fresh seeds 6000-6042: --first-seed)


def cases(quick: bool, first_seed: int = FIRST_SEED,
          effect_free: int | None = None) -> list[tuple[list[str], int]]:
    """The suite's (effects, seed) cases; ``first_seed`` moves every seed (new rigs, new
    magnitudes, the same mix of cases), for figures on rigs no version was looked at on.
    ``effect_free``: instead, that many effect-free rigs at consecutive seeds -- the false
    positive rate on a sample large enough to bound it (six per suite cannot tell 0 % from 30 %)."""
    if effect_free is not None:
        if effect_free < 1:
            raise ValueError(f"effect_free must be at least 1, got {effect_free}")
        return [([], first_seed + k) for k in range(effect_free)]
    out: list[tuple[list[str], int]] = []
    seed = first_seed
    n_free, reps, n_pairs, n_gyro = (2, 1, 2, 2) if quick else (6, 3, 6, 4)
    for _ in range(n_free):
        out.append(([], seed))
        seed += 1
    for _ in range(reps):
        for name in fx.CATALOGUE:
            out.append(([name], seed))
            seed += 1
    rng = np.random.default_rng(7)
    allpairs = list(itertools.combinations(fx.CATALOGUE, 2))
    for k in rng.choice(len(allpairs), n_pairs, replace=False):
        out.append((list(allpairs[k]), seed))
        seed += 1
    for _ in range(n_gyro):
        out.append((["gyro_bias_drift"], seed))
        seed += 1
    return out


def diagnose_folder(ds: Path, rep_path: Path, options: Sequence[str] = ()) -> tuple[int, dict, float]:
    """The CLI on a dataset folder exactly as a user runs it (JSON, no plots, console
    silenced; ``options``: further command-line options): (exit code, report or {} on
    failure, seconds)."""
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = gap_main([str(ds), "--json", str(rep_path), "--no-plots", "--quiet", *options])
    elapsed = time.perf_counter() - t0
    return rc, (json.loads(Path(rep_path).read_text()) if rc == 0 else {}), elapsed


SIZE_DETECTABLE_DEG = 0.3  # the diagnosis' own bar for a systematic residual (UNEXPLAINED_ABS_DEG)


# Rigs written apart from the project's model (each imports none of its physics), by module.
OTHER_RIGS = {"independent": "neck_env.gap.independent", "third": "neck_env.gap.third"}


def other_rig(generator: str):
    """The ``generate`` function of one of ``OTHER_RIGS`` (imported on use: a worker loads
    only the rig it runs)."""
    return importlib.import_module(OTHER_RIGS[generator]).generate


def _tilt_xy(path: Path) -> np.ndarray:
    """(N, 2) tilt vector, degrees, of one recording."""
    rec = read_recording(path)
    return np.column_stack(tilt_vec(rec.theta_deg, rec.phi_deg))


def effect_size_deg(ds: Path, effects: list[str], seed: int, generator: str, hard: bool = False,
                    **generate_kwargs) -> float:
    """How far the dataset's effects move the measured tilt: the RMS tilt-vector difference
    (over sqrt 2, as the held-out gap) between ``ds`` and its twin -- the same rig, protocol
    and sensor noise with the effects off. Separates "missed" from "not in the data": an
    effect the baseline or the noise hides is not a failure of the decision rule."""
    if not effects:
        return 0.0
    with tempfile.TemporaryDirectory(prefix="gap_blind_off_") as tmp:
        if generator in OTHER_RIGS:
            # its rig, protocol, effects and noise come from separate streams
            other_rig(generator)(tmp, None, seed=seed, **generate_kwargs)
        else:
            generate(tmp, effects, seed=seed, hard=hard, switched_off=True, **generate_kwargs)
        sq, n = 0.0, 0
        for f in sorted(Path(ds).glob("*.csv")):
            a, b = _tilt_xy(f), _tilt_xy(Path(tmp) / f.name)
            sq += float(((a - b) ** 2).sum()) / 2
            n += len(a)
    return math.sqrt(sq / n)


def run_case(effects: list[str], seed: int, root: Path, hard: bool, baseline: str = "default",
             generator: str = "synthetic", options: Sequence[str] = (), no_meta: bool = False,
             **generate_kwargs) -> dict:
    ds = root / f"ds_{seed}"
    if generator in OTHER_RIGS:
        truth = other_rig(generator)(ds, effects, seed=seed, baseline=baseline, **generate_kwargs)
    else:
        truth = generate(ds, effects, seed=seed, hard=hard, baseline=baseline, **generate_kwargs)
    if no_meta:
        (ds / "meta.json").unlink(missing_ok=True)
    size = effect_size_deg(ds, effects, seed, generator, hard=hard, baseline=baseline,
                           **generate_kwargs)
    rc, rep, elapsed = diagnose_folder(ds, root / f"report_{seed}.json", options)
    return {"seed": seed, "truth": truth["effects"], "rc": rc, "report": rep, "seconds": elapsed,
            "baseline_truth": truth.get("baseline_ratios"), "physical_truth": truth.get("physical"),
            "effect_size_deg": size}


def run_case_task(case: tuple[list[str], int], root: Path | None, run_kwargs: dict) -> dict:
    """``run_case`` for one item of a fan-out; ``root`` None: a temporary folder of the worker
    (a Ray worker may be on another machine), removed afterwards."""
    if root is not None:
        return run_case(*case, root, **run_kwargs)
    with tempfile.TemporaryDirectory(prefix="gap_blind_") as tmp:
        return run_case(*case, Path(tmp), **run_kwargs)


def rate(k: int, n: int) -> str:
    """``k/n = p %`` with its exact (Clopper-Pearson) 95 % interval: 27 datasets pin a rate to
    about +-18 points, six to about +-40, and a target is only missed or met beyond that."""
    if n == 0:
        return "0/0"
    lo, hi = binomtest(k, n).proportion_ci(0.95, method="exact")
    return f"{k}/{n} = {100 * k / n:.0f} % [95 % CI {100 * lo:.0f}-{100 * hi:.0f} %]"


def gyro_localized(rep: dict) -> tuple[bool, bool]:
    """(right signal, right phase) for a gyro-drift dataset: the remaining residual sits in
    the tilt (theta/phi), and it is not concentrated in heating or cooling (a drift is the same
    whether or not a muscle is heated): spread over all phases, or densest at rest."""
    pat = rep.get("localization_remaining_pattern", {})
    sig = pat.get("tilt_share", 0.0) >= 0.8
    phase = pat.get("concentrated_in_phase") in ("all phases alike", "rest")
    return sig, phase


KINDS = ("effect-free", "single", "pair", "gyro_bias_drift")


def kind(truth) -> str:
    """Which of ``KINDS`` a dataset of these true effects is (gyro drift, out of the catalogue,
    counts as its own kind alone or beside an effect)."""
    if "gyro_bias_drift" in truth:
        return "gyro_bias_drift"
    return {0: "effect-free", 1: "single"}.get(len(truth), "pair")


def timing(results: list[dict]) -> str:
    times = [r["seconds"] for r in results]
    return f"diagnosis time per dataset: median {statistics.median(times):.1f} s, max {max(times):.1f} s"


def summarize(results: list[dict]) -> str:
    L = []
    by = {k: [r for r in results if kind(r["truth"]) == k] for k in KINDS}
    free, singles, pairs, gyro = (by[k] for k in KINDS)
    bad = [r for r in results if r["rc"] != 0]
    L.append(f"{len(results)} datasets ({len(free)} effect-free, {len(singles)} single, "
             f"{len(pairs)} pairs, {len(gyro)} gyro_bias_drift); failures: {len(bad)}")

    def top1(r):
        e = r["report"].get("effects", [])
        return e[0]["name"] if e else None

    ok1 = [r for r in singles if top1(r) == next(iter(r["truth"]))]
    okr = [r for r in singles if outcome(r)[1]]  # issue 11's scoring
    named_seeds = {r["seed"] for r in okr}
    okv = [r for r in singles if r["report"].get("verdict") == list(r["truth"])]
    if singles:
        L.append(f"single effects: top-1 {rate(len(ok1), len(singles))}; ranked first and in the "
                 f"verdict {rate(len(okr), len(singles))} (issue 11's targets: own generator "
                 f">= 85 % wide, top-1 >= 90 % on the default baseline; independent >= 80 %); "
                 f"verdict exactly the effect {len(okv)}/{len(singles)} = "
                 f"{100 * len(okv) / len(singles):.0f} %")

    sized = [r for r in singles if r.get("effect_size_deg") is not None]
    if sized:
        # what the data hold: an effect that moves the tilt less than the tool's own bar for a
        # systematic residual is for a sharper protocol, not for a better decision rule
        big = [r for r in sized if r["effect_size_deg"] >= SIZE_DETECTABLE_DEG]
        small = [r for r in sized if r["effect_size_deg"] < SIZE_DETECTABLE_DEG]
        for what, rs in ((f">= {SIZE_DETECTABLE_DEG}", big), (f"< {SIZE_DETECTABLE_DEG}", small)):
            named = [r for r in rs if r["seed"] in named_seeds]
            L.append(f"single effects moving the tilt by {what} deg RMS (with the effect off, same "
                     f"rig and noise): ranked first and in the verdict {rate(len(named), len(rs))}"
                     "; missed: "
                     + (", ".join(f"{next(iter(r['truth']))} {r['effect_size_deg']:.2f}"
                                  for r in sorted(rs, key=lambda r: r["effect_size_deg"])
                                  if r["seed"] not in named_seeds) or "none"))

    # does the report's own `absorption` tell the misses? (the true effect, at the catalogue's
    # size, on each dataset's held-out recordings)
    hid = {}
    for r in singles:
        name = next(iter(r["truth"]))
        a = {x["effect"]: x for x in r["report"].get("absorption", [])}.get(name)
        if a is not None:
            hid.setdefault(r["seed"] in named_seeds, []).append(a["absorbed"])
    if hid:
        L.append("the report's absorption of the true effect (share a baseline shift hides): "
                 + "; ".join(f"{'named' if k else 'missed'} median {100 * statistics.median(v):.0f} %"
                             f" ({sum(x >= 0.8 for x in v)}/{len(v)} at 80 % or more)"
                             for k, v in sorted(hid.items(), reverse=True)))

    def top2(r):
        rep = r["report"]
        if len(rep.get("verdict", [])) == 2:
            return set(rep["verdict"])
        if rep.get("pairs"):
            return set(rep["pairs"][0]["effects"])
        return {e["name"] for e in rep.get("effects", [])[:2]}

    okp = [r for r in pairs if top2(r) == set(r["truth"])]
    okpv = [r for r in pairs if outcome(r)[1]]
    if pairs:
        # issue 11 scores a pair right when both are in the top 2 *and in the verdict*: the
        # verdict being exactly the pair; "both in the top 2" alone is the ranking's share
        L.append(f"pairs: both in the top 2 {rate(len(okp), len(pairs))}; verdict exactly the "
                 f"pair {rate(len(okpv), len(pairs))} (issue 11's scoring; targets: own >= 70 %, "
                 f"independent >= 60 %)")
    fp = [r for r in free if not outcome(r)[1]]
    which = ", ".join(f"{r['seed']}: {r['report']['verdict']}" for r in fp)
    L.append(f"effect-free: false positives {rate(len(fp), len(free))} (target <= 10 %)"
             + (f" [{which}]" if fp else "")
             + f"; flagged unexplained {sum(bool(r['report'].get('unexplained')) for r in free)}/{len(free)}")
    # a verdict naming an effect the rig does not have misleads a user more than a miss does
    absent = [(r, sorted(set(r["report"].get("verdict", [])) - set(r["truth"])))
              for r in singles + pairs + gyro]
    wrong = [f"{r['seed']} {'+'.join(r['truth'])}: {'+'.join(extra)}" for r, extra in absent if extra]
    L.append(f"datasets with an effect present whose verdict also names one absent: "
             f"{len(wrong)}/{len(absent)}" + (f" [{', '.join(wrong)}]" if wrong else ""))
    amb = [r for r in singles if next(iter(r["truth"])) in
           {a["effect"] for a in r["report"].get("ambiguous", [])}]
    if singles:
        L.append(f"single effects listed as ambiguous with a baseline shift (not in the verdict): "
                 f"{len(amb)}/{len(singles)} "
                 + str(sorted(f"{next(iter(r['truth']))} ~ {','.join(a['with'])}" for r in amb
                              for a in r["report"]["ambiguous"] if a["effect"] in r["truth"])))
    L.append(f"effect-free: ambiguous entries {sum(len(r['report'].get('ambiguous', [])) for r in free)} "
             f"over {len(free)} datasets " + str([[a["effect"] for a in r["report"].get("ambiguous", [])]
                                                   for r in free]))
    # in physical units, so that any generator's rig compares, whatever its model's structure
    for name, what in (("convection_W_m2K", "h (W/m^2K)"),
                       ("cooling_time_constant_s", "cooling time constant m c/(h A)")):
        rows = []  # (fitted / true - 1, identified, truth within the reported +- 2 std)
        for r in free:
            pt = r.get("physical_truth") or {}
            fit = r["report"].get("calibration", {}).get(name)
            if fit and name in pt:
                rows.append((fit["value"] / pt[name] - 1, fit.get("identified"),
                             abs(fit["value"] - pt[name]) <= 2 * fit.get("std", 0.0)))
        if rows:
            L.append(f"effect-free, {what} fitted / true - 1 = "
                     + ", ".join(f"{100 * e:+.0f} %{'' if ok else ' (not identified)'}"
                                 for e, ok, _ in rows)
                     + f"; within +-25 %: {sum(abs(e) <= 0.25 for e, _, _ in rows)}/{len(rows)}"
                     + f"; truth within the reported +-2 std: {sum(held for _, _, held in rows)}/{len(rows)}")
    red = []
    for r in singles:
        name = next(iter(r["truth"]))
        for e in r["report"].get("effects", []):
            if e["name"] == name:
                red.append(1 - e["heldout_gap_after"] / e["heldout_gap_before"])
    corr = [r["report"]["corrected"]["heldout_reduction"] for r in singles + pairs if r["report"]]
    if red:
        L.append(f"held-out gap reduction with the true effect added: median {100 * statistics.median(red):.0f} % "
                 f"(target >= 60 %), min {100 * min(red):.0f} %; with the verdict model (singles + pairs): "
                 f"median {100 * statistics.median(corr):.0f} %")
    # the measured currents (--current-sensor), decision by decision against the truth
    sensed = [r for r in results if (r["report"] or {}).get("measured_currents")]
    for name in ("actuation_delay", "supply_limit"):
        if not sensed:
            break
        has = [r for r in sensed if name in r["truth"]]
        rest = [r for r in sensed if name not in r["truth"]]
        dec = lambda r: r["report"]["measured_currents"].get("decides", {}).get(name)
        L.append(f"measured currents, {name}: found on {sum(dec(r) is True for r in has)}/"
                 f"{len(has)} rigs with it (undecided {sum(dec(r) is None for r in has)}); "
                 f"ruled out on {sum(dec(r) is False for r in rest)}/{len(rest)} without it "
                 f"(found on {[r['seed'] for r in rest if dec(r) is True]}); verdict changed by "
                 f"them: named on {[r['seed'] for r in sensed if r['report'].get('verdict_by_currents', {}).get(name) == 'named']}"
                 f", dropped on {[r['seed'] for r in sensed if r['report'].get('verdict_by_currents', {}).get(name) == 'dropped']}")
    # where the verdict model's residual still sits where several muscles are warm, the console
    # reads it as structure (localize.warm_muscles): how often, with and without an effect
    def coact(rs):
        return sum((r["report"].get("localization_remaining_pattern") or {})
                   .get("concentrated_in_activation") == "several" for r in rs)
    L.append(f"remaining residual concentrated where several muscles are warm (read as structure): "
             f"effect-free {coact(free)}/{len(free)}, single {coact(singles)}/{len(singles)}, "
             f"pairs {coact(pairs)}/{len(pairs)}, gyro drift {coact(gyro)}/{len(gyro)}")
    if not singles and not gyro:  # an effect-free suite: the rest is about effects
        L.append(timing(results))
        return "\n".join(L)
    gy_un = [r for r in gyro if r["report"].get("unexplained")]
    loc = [gyro_localized(r["report"]) for r in gyro]
    L.append(f"gyro_bias_drift: unexplained {len(gy_un)}/{len(gyro)}; remaining residual in the tilt "
             f"signals {sum(a for a, _ in loc)}/{len(gyro)}, not concentrated in heating/cooling "
             f"(all phases alike or rest) {sum(b for _, b in loc)}/{len(gyro)}; verdicts "
             f"{[r['report'].get('verdict') for r in gyro]}")
    for r in gyro:
        rep = r["report"]
        L.append(f"    seed {r['seed']} drift {r['truth']['gyro_bias_drift']['drift_dps_per_s']:.4f} deg/s/s: "
                 f"unexplained {rep.get('unexplained')}; " + "; ".join(rep.get("unexplained_reasons", [])))
    # confusion
    L.append("")
    L.append("confusion (single effects): truth -> top-1 [runner-up: share of the gap it also removes]")
    conf: dict[tuple[str, str], int] = {}
    runner: dict[str, list[tuple[str, float]]] = {}
    for r in singles:
        name = next(iter(r["truth"]))
        eff = r["report"].get("effects", [])
        conf[(name, top1(r))] = conf.get((name, top1(r)), 0) + 1
        if len(eff) > 1:
            other = eff[1] if eff[0]["name"] == name else eff[0]
            runner.setdefault(name, []).append((other["name"], other["heldout_reduction"]))
    for name in fx.CATALOGUE:
        got = {k[1]: v for k, v in conf.items() if k[0] == name}
        ru = runner.get(name, [])
        L.append(f"  {name:25s} -> " + ", ".join(f"{k} x{v}" for k, v in got.items())
                 + "   [" + ", ".join(f"{n} {100 * x:.0f} %" for n, x in ru) + "]")
    close = {}
    for name, ru in runner.items():
        for other, x in ru:
            if x > 0.3:
                close.setdefault(frozenset({name, other}), []).append(x)
    if close:
        L.append("confusable pairs (runner-up removes > 30 % of the gap too), and why:")
        for k, xs in sorted(close.items(), key=lambda kv: -max(kv[1])):
            a, b = sorted(k)
            L.append(f"  {a} / {b}: up to {100 * max(xs):.0f} % -- "
                     + WHY.get(k, "overlapping signatures (see effects.py)"))
    L.append("")
    L.append(timing(results))
    return "\n".join(L)


def load_results(folders: Sequence[str | Path]) -> list[dict]:
    """The finished datasets of ``--out`` folders, pooled, in seed order. A seed of one
    generator met twice is refused: two runs of one rig are not two samples."""
    out: dict[tuple[str, int], dict] = {}
    for folder in folders:
        files = sorted(Path(folder).glob("result_*.json"))
        if not files:
            raise SystemExit(f"{folder}: no result_<seed>.json (not a gap_blind --out folder, "
                             f"or nothing finished there yet)")
        setup_file = Path(folder) / "suite.json"
        setup = json.loads(setup_file.read_text()) if setup_file.exists() else {}
        rig = setup.get("generator", "synthetic")
        for f in files:
            r = json.loads(f.read_text())
            key = (rig, r["seed"])
            if key in out:
                raise SystemExit(f"{f}: seed {r['seed']} of the {rig} generator is already in "
                                 f"another folder: pool different seeds, not reruns")
            out[key] = r
    return [out[k] for k in sorted(out, key=lambda k: (k[1], k[0]))]


def outcome(r: dict) -> tuple[str, bool]:
    """(what the diagnosis made of one dataset, right by issue 11's scoring): effect-free and
    gyro drift -- no verdict (gyro drift also ``unexplained``); a single effect ranked first and
    in the verdict; a pair exactly the verdict."""
    truth, rep = sorted(r["truth"]), r["report"]
    verdict = rep.get("verdict", [])
    ranked = [e["name"] for e in rep.get("effects", [])]
    if r["rc"] != 0:
        return "failed", False
    k = kind(truth)
    if k == "effect-free":
        return ("no verdict", True) if not verdict else (f"false positive {verdict}", False)
    if k == "gyro_bias_drift":
        ok = not verdict and bool(rep.get("unexplained"))
        return ("unexplained, nothing blamed" if ok
                else f"verdict {verdict}, unexplained {rep.get('unexplained')}"), ok
    if k == "single":
        ok = bool(ranked) and ranked[0] == truth[0] and truth[0] in verdict
        return ("named" if ok else f"missed (first {ranked[0] if ranked else '-'}, "
                f"verdict {verdict})"), ok
    ok = set(verdict) == set(truth)
    return ("exactly the pair" if ok else f"verdict {verdict}"), ok


def compare_runs(a: list[dict], b: list[dict]) -> str:
    """Two runs on the same datasets (seeds and truths; e.g. two protocols, two versions):
    every dataset whose outcome changed, and per kind the paired counts with an exact McNemar
    test (two-sided binomial on the datasets only one run gets right) -- the paired comparison
    tells apart two runs whose separate intervals overlap."""
    A, B = {r["seed"]: r for r in a}, {r["seed"]: r for r in b}
    common = sorted(set(A) & set(B))
    for s in common:
        if sorted(A[s]["truth"]) != sorted(B[s]["truth"]):
            raise SystemExit(f"seed {s}: truth {sorted(A[s]['truth'])} in one run, "
                             f"{sorted(B[s]['truth'])} in the other: not the same datasets")
    if not common:
        raise SystemExit("the two runs share no seed: nothing to compare")
    L = [f"{len(common)} datasets in both runs ({len(set(A) - set(B))} only in the first, "
         f"{len(set(B) - set(A))} only in the second)"]
    for k in KINDS:
        seeds = [s for s in common if kind(A[s]["truth"]) == k]
        if not seeds:
            continue
        oa = {s: outcome(A[s]) for s in seeds}
        ob = {s: outcome(B[s]) for s in seeds}
        only_a = sum(oa[s][1] and not ob[s][1] for s in seeds)
        only_b = sum(ob[s][1] and not oa[s][1] for s in seeds)
        p = binomtest(min(only_a, only_b), only_a + only_b).pvalue if only_a + only_b else 1.0
        L.append(f"{k}: right in the first {sum(o[1] for o in oa.values())}/{len(seeds)}, in the "
                 f"second {sum(o[1] for o in ob.values())}/{len(seeds)}; only the first {only_a}, "
                 f"only the second {only_b} (exact McNemar p = {p:.2g})")
        for s in seeds:
            if oa[s][0] != ob[s][0]:
                L.append(f"    seed {s} {sorted(A[s]['truth']) or '-'}: {oa[s][0]} -> {ob[s][0]}")
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--hard", action="store_true", help="rigs further from the model")
    ap.add_argument("--baseline", choices=("default", "wide"), default="default",
                    help="wide: every rig's baseline drawn far from the defaults")
    ap.add_argument("--generator", choices=("synthetic", *OTHER_RIGS), default="synthetic",
                    help="independent, third: the structurally independent rigs "
                    "(neck_env.gap.independent, neck_env.gap.third)")
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED,
                    help=f"seed of the suite's first dataset (default {FIRST_SEED}, the suite the "
                    "documented figures come from); another value draws a fresh suite of the same "
                    "mix: rigs and magnitudes no version of the diagnosis was looked at on")
    ap.add_argument("--only", default=None, help="comma-separated seeds to run (debugging)")
    ap.add_argument("--out", default=None, help="keep datasets, reports and results.json here "
                    "(with --ray: results.json only; datasets live in the workers' temp folders)")
    ap.add_argument("--resume", action="store_true",
                    help="with --out: load the datasets already diagnosed there (result_<seed>.json, "
                    "written as each one finishes) and run only the rest; the summary covers all")
    ap.add_argument("--datasets", type=int, default=None, help="only the first N cases of the suite")
    ap.add_argument("--protocol", choices=PROTOCOLS, default=None,
                    help="the recording protocol of every dataset (neck_env.experiments; "
                    "default: the generator's, 'mixed')")
    ap.add_argument("--recordings", type=int, default=None,
                    help="recordings per dataset (default: the generator's)")
    ap.add_argument("--duration", type=float, default=None,
                    help="seconds per recording (default: the generator's)")
    ap.add_argument("--sample-hz", type=float, default=None,
                    help="the rigs' logging rate, Hz (default: the generator's, 50): another "
                         "lab's logger")
    ap.add_argument("--thermistors", choices=("drawn", "always", "never"), default="drawn",
                    help="T1..T3 columns: drawn per dataset (the default), in every dataset (as "
                    "a rig logging its thermistors records), or in none")
    ap.add_argument("--current-sensor", action="store_true",
                    help="the rigs log a Hall sensor's reading of the current that flowed "
                         "(i1_meas..i3_meas), which the diagnosis reads as direct evidence of an "
                         "actuation delay or a supply limit")
    ap.add_argument("--starts", choices=("upright", "cooled"), default=None,
                    help="every recording starts upright (the default) or "
                         "where the rig's wait for rest leaves the neck (cooled: a backbone with "
                         "friction holds it off upright, as on a real rig)")
    ap.add_argument("--convection", choices=tuple(CONVECTION_LAWS), default=None,
                    help="independent rig only: the springs' h constant (its default) or "
                    "following free convection in still air (natural: h ~ dT^0.25, "
                    "thin_wire: dT^0.15; no effect)")
    ap.add_argument("--no-wire-meta", action="store_true",
                    help="leave the wire's diameter and specific heat out of meta.json (h is then "
                    "not identifiable; the cooling time constant still is)")
    ap.add_argument("--no-meta", action="store_true",
                    help="no meta.json at all (a rig that logs the CSV columns only: the room, "
                    "the rate and the wire unknown)")
    ap.add_argument("--fit-spring-modulus", action="store_true",
                    help="diagnose with neck-gap --fit-spring-modulus (the springs' martensite "
                    "modulus fitted as part of the baseline)")
    ap.add_argument("--fit-terminals", action="store_true",
                    help="diagnose with neck-gap --fit-terminals (the heat the springs drain into "
                    "their terminals fitted as part of the baseline)")
    ap.add_argument("--still-air", action="store_true",
                    help="diagnose with neck-gap --still-air (free convection a structural rival "
                    "of a convection change)")
    ap.add_argument("--effect-free", type=int, default=None, metavar="N",
                    help="instead of the suite: N effect-free rigs at consecutive seeds from "
                    "--first-seed (the false-positive rate with an interval narrow enough to "
                    "compare with the 10 %% target)")
    ap.add_argument("--summarize", nargs="+", default=None, metavar="DIR",
                    help="diagnose nothing: print the summary of the finished datasets "
                    "(result_<seed>.json) in these --out folders, pooled (e.g. two seed ranges of "
                    "one generator, for a narrower interval)")
    ap.add_argument("--compare", nargs=2, default=None, metavar=("DIR_A", "DIR_B"),
                    help="diagnose nothing: compare two finished runs on the same seeds (two "
                    "protocols, two versions): the datasets whose outcome changed and a paired "
                    "(McNemar) test per kind")
    add_ray_argument(ap, "datasets")
    args = ap.parse_args(argv)
    if args.summarize:
        print(summarize(load_results(args.summarize)))
        return 0
    if args.compare:
        print(compare_runs(*(load_results([d]) for d in args.compare)))
        return 0
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="gap_blind_"))
    root.mkdir(parents=True, exist_ok=True)
    gen = {k: v for k, v in (("protocol", args.protocol),
                             ("n_recordings", args.recordings), ("duration_s", args.duration),
                             ("sample_hz", args.sample_hz),
                             ("temperatures", {"always": True, "never": False}.get(args.thermistors)),
                             ("wire_meta", False if args.no_wire_meta else None),
                             ("current_sensor", True if args.current_sensor else None),
                             ("starts", args.starts),
                             ("convection", args.convection))
           if v is not None}
    run_kwargs = {"hard": args.hard, "baseline": args.baseline, "generator": args.generator, **gen}
    # only when set: folders of earlier runs resume as they were
    options = [flag for flag, on in (("--fit-spring-modulus", args.fit_spring_modulus),
                                     ("--fit-terminals", args.fit_terminals),
                                     ("--still-air", args.still_air)) if on]
    if options:
        run_kwargs["options"] = options
    if args.no_meta:  # only when set: folders of earlier runs resume as they were
        run_kwargs["no_meta"] = True
    only = {int(x) for x in args.only.split(",")} if args.only else None
    if args.resume and not args.out:
        ap.error("--resume needs --out (the folder of the interrupted run)")
    if args.convection is not None and args.generator != "independent":
        ap.error(f"--convection is the independent rig's option, not the {args.generator} "
                 f"generator's")
    if args.effect_free is not None and args.effect_free < 1:
        ap.error(f"--effect-free needs at least one dataset, got {args.effect_free}")
    every = cases(args.quick, args.first_seed, args.effect_free)
    suite = [c for c in every if only is None or c[1] in only][:args.datasets]
    if not suite:
        seeds = [c[1] for c in every]
        ap.error(f"--only {args.only} selects none of this suite's seeds "
                 f"({min(seeds)}-{max(seeds)}; --first-seed moves them)")
    done: list[dict] = []
    if args.out:
        # what the folder's datasets were drawn with: a resume must draw the rest the same way
        setup = {"quick": args.quick, **run_kwargs}
        if args.first_seed != FIRST_SEED:  # older folders have no key: the default suite
            setup["first_seed"] = args.first_seed
        if args.effect_free is not None:
            setup["effect_free"] = args.effect_free
        setup_file = root / "suite.json"
        if args.resume and setup_file.exists():
            old = json.loads(setup_file.read_text())
            if old != setup:
                raise SystemExit(f"{root} holds a suite run with {old}; this run is {setup}: "
                                 f"resume with the same options, or use another --out")
        setup_file.write_text(json.dumps(setup))
    if args.resume:
        for c in list(suite):
            f = root / f"result_{c[1]}.json"
            if f.exists():
                r = json.loads(f.read_text())
                if sorted(r["truth"]) != sorted(c[0]):
                    raise SystemExit(f"{f}: truth {sorted(r['truth'])} is not this suite's case "
                                     f"{sorted(c[0])} for seed {c[1]} (another suite's folder?)")
                if "effect_size_deg" not in r and (root / f"ds_{c[1]}").is_dir():
                    # a folder from before the size was measured: cheap to add (generation only)
                    r["effect_size_deg"] = effect_size_deg(
                        root / f"ds_{c[1]}", c[0], c[1], args.generator, hard=args.hard,
                        baseline=args.baseline, **gen)
                    f.write_text(json.dumps(r))
                done.append(r)
                suite.remove(c)
        print(f"resuming: {len(done)} dataset(s) already diagnosed in {root}, {len(suite)} to run",
              flush=True)

    def line(o, k, n):
        if o.error is not None:
            print(f"seed {suite[o.index][1]}: FAILED {o.error}", flush=True)
            return
        r, rep = o.value, o.value["report"]
        if args.out:  # as each finishes: an interrupted run resumes from these
            (root / f"result_{r['seed']}.json").write_text(json.dumps(dict(r, node_id=o.node_id)))
        where = "" if o.node_id == "local" else f" [node {o.node_id[:8]}]"
        print(f"seed {r['seed']}: truth {sorted(r['truth']) or '-'} -> verdict {rep.get('verdict')} "
              f"unexplained {rep.get('unexplained')} top {[e['name'] for e in rep.get('effects', [])[:2]]} "
              f"({r['seconds']:.1f} s){where}", flush=True)

    try:
        work = partial(run_case_task, root=None if args.ray else root, run_kwargs=run_kwargs)
        outcomes = fan_out(work, suite, args.ray, progress=line)
        results = done + [dict(o.value, node_id=o.node_id) for o in outcomes if o.error is None]
        results.sort(key=lambda r: r["seed"])
        (root / "results.json").write_text(json.dumps(
            [{k: v for k, v in r.items()} for r in results], indent=1))
        print()
        failed = [suite[o.index][1] for o in outcomes if o.error is not None]
        if failed:
            print(f"{len(failed)} dataset(s) raised (seeds {failed}); left out of the summary")
        print(summarize(results))
    finally:
        if not args.out:
            shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
