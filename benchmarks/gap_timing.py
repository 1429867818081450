"""How long the sim-to-real diagnosis takes on a dataset of the issue's size (target <= 120 s).

    python benchmarks/gap_timing.py            # 3 datasets: none, one effect, two effects
    python benchmarks/gap_timing.py --repeat 3

Each dataset is ~15 recordings of 30 s at 50 Hz (``neck_env.gap.synthetic``, with spring
temperatures, the heavier case), diagnosed through the CLI exactly as a user runs it, plots and
exported model included. Printed: wall time per dataset against the 120 s budget, the split
into the diagnosis's stages, and, as a reference measured in the same run, the wall time of one
batched simulation of the whole dataset (so the ratio says how many model evaluations the
diagnosis spends, independent of how busy the machine is).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import tempfile
import time
from pathlib import Path

from neck_env.gap.cli import main as gap_main
from neck_env.gap.model import Model, prepare
from neck_env.gap.synthetic import generate
from neck_env.recording import read_dataset

BUDGET_S = 120.0
CASES = [([], 21), (["backbone_viscoelasticity"], 22), (["thermal_coupling", "sma_fatigue"], 23)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="diagnose each dataset this many times")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="gap_timing_"))
    print(f"{'dataset':36s} {'recordings':>10s} {'wall s':>8s} {'sim ref s':>9s} {'ratio':>6s}  stages")
    worst = 0.0
    for effects, seed in CASES:
        ds = root / f"ds_{seed}"
        generate(ds, effects, seed=seed, temperatures=True)
        data = read_dataset(ds)
        model = Model(prepare(data))
        model.predict([{}])  # compile / warm caches outside the timing
        t0 = time.perf_counter()
        model.predict([{}])
        ref = time.perf_counter() - t0
        walls = []
        for k in range(args.repeat):
            out = root / f"report_{seed}_{k}.json"
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                rc = gap_main([str(ds), "--json", str(out)])
            walls.append(time.perf_counter() - t0)
            if rc != 0:
                raise SystemExit(f"diagnosis failed on {ds} (exit {rc})")
        rep = json.loads(out.read_text())
        wall = statistics.median(walls)
        worst = max(worst, max(walls))
        stages = ", ".join(f"{k.removesuffix('_s')} {v:.1f}" for k, v in rep.get("timing_s", {}).items())
        label = "+".join(effects) or "effect-free"
        print(f"{label:36s} {len(data):10d} {wall:8.1f} {ref:9.3f} {wall / ref:6.0f}  {stages}")
    verdict = "met" if worst <= BUDGET_S else f"MISSED by {worst - BUDGET_S:.0f} s"
    print(f"\nslowest diagnosis {worst:.1f} s against the {BUDGET_S:.0f} s budget: {verdict}")


if __name__ == "__main__":
    main()
