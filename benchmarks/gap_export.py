"""Does NeckTrack-v0 built from a diagnosis' export move as the rig does, on recordings the
diagnosis never saw?

    python benchmarks/gap_export.py --generator independent --first-seed 12300 --datasets 8
    python benchmarks/gap_export.py --generator independent --convection natural --still-air
    python benchmarks/gap_export.py --generator third --datasets 6 --out runs/export --resume

For each seed: a rig written apart from the model (its baseline drawn wide, thermistors on every
spring, effect-free unless ``--effects``) records the mixed protocol, which ``neck-gap``
diagnoses; the *same rig* (the generators draw the rig, the protocol and the noise from separate
streams) then records another lab's pulse timing (protocol ``drawn``), and each of those
recordings is replayed in ``NeckTrack-v0`` (``neck_env.gap.replay``) built from

* the export as written (``REPORT_params.json``: the baseline, the verdict's effects and, where
  one was significant held out, the rig's structural discrepancy: ``docs/gap.md`` item 11),
* the verdict model alone (the export before structure was carried), and
* the defaults.

Printed per dataset: the structure exported (if any), the median replay error per recording of
each, and over the datasets the paired ratio export / verdict-only (median, and the
datasets where carrying the structure made the replay worse).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import wilcoxon

from neck_env.gap import diagnose as D
from neck_env.gap import report as R
from neck_env.gap.replay import replay_gap_deg, report_offset_deg
from neck_env.recording import read_dataset

# rigs written apart from the model, whose IMU zero offset (the mount) is the rig's: the same
# for both datasets of a seed (the own generator draws it after the protocol)
GENERATORS = ("independent", "third")


def generate(generator: str, out: Path, seed: int, protocol: str, effects: list[str],
             convection: str) -> dict:
    if generator == "independent":
        from neck_env.gap.independent import generate as g
        return g(out, effects, seed=seed, protocol=protocol, temperatures=True, convection=convection)
    from neck_env.gap.third import generate as g
    return g(out, effects, seed=seed, protocol=protocol, temperatures=True)


def run_seed(a: argparse.Namespace, seed: int, root: Path) -> dict:
    done = root / f"result_{seed}.json"
    if a.resume and done.exists():
        return json.loads(done.read_text())
    seen, unseen = root / f"ds_{seed}", root / f"ds_{seed}_drawn"
    truth = generate(a.generator, seen, seed, "mixed", a.effects, a.convection)
    generate(a.generator, unseen, seed, "drawn", a.effects, a.convection)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        dg = D.diagnose(read_dataset(seen), still_air=a.still_air)
        rep = R.write_outputs(dg, root / f"report_{seed}.json", seen, make_plots=False)
    seconds = time.perf_counter() - t0
    effects = json.loads(Path(rep["outputs"]["effects"]).read_text())
    effects.pop("imu_misalignment", None)  # the replay compares the true tilt (replay.py)
    verdict_only = dg.model.params_of(dg.final.values)
    off = report_offset_deg(rep)
    recs = read_dataset(unseen).recordings
    out = {"seed": seed, "truth": truth["effects"], "verdict": rep["verdict"],
           "export": rep["export"], "seconds": seconds,
           "exported_deg": [replay_gap_deg(r, rep["outputs"]["params"], effects, off) for r in recs],
           "verdict_only_deg": [replay_gap_deg(r, verdict_only, effects, off) for r in recs],
           "defaults_deg": [replay_gap_deg(r, None) for r in recs]}
    done.write_text(json.dumps(out, indent=1))
    return out


def summarize(results: list[dict]) -> str:
    L = [f"{'seed':>6s} {'verdict':24s} {'structure exported':34s} {'export':>7s} "
         f"{'verdict only':>12s} {'defaults':>8s}   (median replay RMS per recording, deg)"]
    ratios = []
    for r in results:
        x = r["export"]
        st = (f"{x['structure']} " + ", ".join(f"{k} {v:.3g}" for k, v in x["params"].items())
              if x["structure"] is not None and x["exported"] else "none")
        e, v, d = (float(np.median(r[k])) for k in ("exported_deg", "verdict_only_deg", "defaults_deg"))
        L.append(f"{r['seed']:>6d} {','.join(r['verdict']) or '-':24s} {st:34s} {e:7.3f} {v:12.3f} {d:8.3f}")
        if x["structure"] is not None and x["exported"]:
            ratios.append((e, v))
    n = len(results)
    L.append(f"structure exported on {len(ratios)}/{n} datasets")
    if ratios:
        q = [e / v for e, v in ratios]
        worse = sum(e > v for e, v in ratios)
        L.append(f"  median replay error, export / verdict only: median ratio {statistics.median(q):.3f} "
                 f"(range {min(q):.3f}-{max(q):.3f}); worse on {worse}/{len(ratios)}")
        if len(ratios) >= 6:
            p = wilcoxon([e for e, _ in ratios], [v for _, v in ratios]).pvalue
            L.append(f"  paired Wilcoxon signed-rank p = {p:.3g}")
    alle = [float(np.median(r["exported_deg"])) for r in results]
    alld = [float(np.median(r["defaults_deg"])) for r in results]
    L.append(f"over all {n}: median of the per-dataset medians, export {statistics.median(alle):.3f} deg, "
             f"defaults {statistics.median(alld):.3f} deg; diagnosis {statistics.median(r['seconds'] for r in results):.0f} s "
             f"per dataset (median)")
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generator", choices=GENERATORS, default="independent")
    ap.add_argument("--first-seed", type=int, default=12300)
    ap.add_argument("--datasets", type=int, default=8)
    ap.add_argument("--effects", default="", help="comma-separated effects every rig holds (default none)")
    ap.add_argument("--convection", default="constant", help="independent rig: constant, natural, thin_wire")
    ap.add_argument("--still-air", action="store_true", help="diagnose with neck-gap --still-air")
    ap.add_argument("--out", type=Path, default=Path("runs/gap_export"))
    ap.add_argument("--resume", action="store_true", help="keep the seeds already done in --out")
    ap.add_argument("--summarize", action="store_true", help="print the results in --out only")
    a = ap.parse_args(argv)
    a.effects = [e for e in a.effects.split(",") if e]
    a.out.mkdir(parents=True, exist_ok=True)
    if a.summarize:
        results = [json.loads(p.read_text()) for p in sorted(a.out.glob("result_*.json"))]
    else:
        results = []
        for seed in range(a.first_seed, a.first_seed + a.datasets):
            results.append(run_seed(a, seed, a.out))
            print(summarize(results[-1:]).splitlines()[1], flush=True)
    if not results:
        print(f"no results in {a.out}", file=sys.stderr)
        return 2
    print(summarize(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
