"""The diagnosis on dataset shapes the blind suites never use.

    python benchmarks/gap_shapes.py                         # 10 shapes x (effect-free + 3 effects)
    python benchmarks/gap_shapes.py --shapes hz100,rec4x30 --effects - --out runs/shapes
    python benchmarks/gap_shapes.py --first-seed 13300            # fresh rigs

``benchmarks/gap_blind.py`` draws every dataset as 15 recordings x 30 s at 50 Hz of the mixed
protocol with a ``meta.json``. A rig's own recordings will differ: another IMU rate, fewer and
longer recordings, only the paper's pulses, no metadata. Each shape here is a dataset of the
structurally independent rig (``neck_env.gap.independent``, baseline drawn wide) diagnosed
through the CLI exactly as a user runs it. Printed per dataset: the verdict, whether the true
effect is ranked first and in the verdict, ``unexplained``, and the run time (target: at most
2 minutes per dataset of ~15 recordings x 30 s at 50 Hz; the longer shapes hold up to 4x the
samples).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gap_blind import diagnose_folder  # noqa: E402  (a sibling script)

from neck_env import effects as fx  # noqa: E402
from neck_env.gap.independent import generate  # noqa: E402

SHAPES: dict[str, dict] = {
    "hz100": dict(sample_hz=100.0),
    "hz25": dict(sample_hz=25.0),
    "rec8x60": dict(n_recordings=8, duration_s=60.0),
    "rec25x20": dict(n_recordings=25, duration_s=20.0),
    "rec4x30": dict(n_recordings=4, duration_s=30.0),
    "rec15x60_100hz": dict(n_recordings=15, duration_s=60.0, sample_hz=100.0),
    "paper": dict(protocol="paper"),  # only the paper's single-muscle pulses
    "rig": dict(protocol="rig"),  # the rig protocol: long cooling tails, repeated pulses
    "drawn": dict(protocol="drawn"),  # another lab's timing: pulse starts, lengths and levels
    "nometa": dict(),  # meta.json removed: sample rate from t, ambient from the data
}
# one effect of each kind of signature: a sensor, a timing, a heat-flow change
EFFECTS = ("", "imu_misalignment", "actuation_delay", "convection_change")


FIRST_SEED = 2000


def seed_of(effect: str, first_seed: int = FIRST_SEED) -> int:
    """One seed per effect, the same whichever effects a run asks for ("" effect-free);
    ``first_seed`` moves them all (rigs no version was looked at on)."""
    if effect in EFFECTS:
        return first_seed + EFFECTS.index(effect)
    return first_seed + 10 + list(fx.CATALOGUE).index(effect)


def run(shape: str, effect: str, seed: int, root: Path) -> dict:
    ds = root / f"{shape}_{effect or 'none'}_{seed}"
    if ds.exists():
        shutil.rmtree(ds)
    generate(ds, [effect] if effect else [], seed=seed, baseline="wide", **SHAPES[shape])
    if shape == "nometa":
        (ds / "meta.json").unlink()
    rc, rep, seconds = diagnose_folder(ds, ds.with_name(ds.name + "_report.json"))
    top = [e["name"] for e in rep.get("effects", [])[:2]]
    verdict = rep.get("verdict")
    ok = (verdict == [] if not effect
          else bool(top) and top[0] == effect and effect in (verdict or []))
    return {"shape": shape, "effect": effect, "seed": seed, "rc": rc, "verdict": verdict,
            "top": top, "unexplained": rep.get("unexplained"), "ok": ok, "seconds": seconds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", default=",".join(SHAPES),
                    help=f"comma-separated, of {', '.join(SHAPES)}")
    ap.add_argument("--effects", default=None,
                    help="comma-separated effect names, '-' for effect-free (a list that "
                         "starts with it needs the '=': --effects=-,actuation_delay) "
                         "(default: effect-free, imu_misalignment, actuation_delay, "
                         "convection_change)")
    ap.add_argument("--out", default=None, help="keep datasets and reports here")
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED,
                    help="moves every seed: fresh rigs and magnitudes, the same cases "
                         "(default %(default)s)")
    args = ap.parse_args(argv)
    shapes = args.shapes.split(",")
    bad = [s for s in shapes if s not in SHAPES]
    if bad:
        ap.error(f"unknown shape(s) {bad}; known: {list(SHAPES)}")
    names = (list(EFFECTS) if args.effects is None
             else ["" if n == "-" else n for n in args.effects.split(",")])
    unknown = [n for n in names if n and n not in fx.CATALOGUE]
    if unknown:
        ap.error(f"unknown effect(s) {unknown}; known: {list(fx.CATALOGUE)}")
    effects = [(n, seed_of(n, args.first_seed)) for n in names]
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="gap_shapes_"))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    for effect, seed in effects:
        for shape in shapes:
            r = run(shape, effect, seed, root)
            rows.append(r)
            print(f"{shape:15s} {effect or 'effect-free':18s} seed {seed}: verdict {r['verdict']} "
                  f"top {r['top']} unexplained {r['unexplained']} "
                  f"{'OK' if r['ok'] else 'MISS'} ({r['seconds']:.1f} s)", flush=True)
    (root / "results.json").write_text(json.dumps(rows, indent=1))
    print()
    for effect, _ in effects:
        sel = [r for r in rows if r["effect"] == effect]
        what = ("empty verdict" if not effect else "ranked first and in the verdict")
        print(f"{effect or 'effect-free':18s} {what}: {sum(r['ok'] for r in sel)}/{len(sel)}")
    secs = sorted(r["seconds"] for r in rows)
    print(f"failures (exit code != 0): {sum(r['rc'] != 0 for r in rows)}; time per dataset: "
          f"median {secs[len(secs) // 2]:.1f} s, max {secs[-1]:.1f} s")
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
