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
  the held-out data showed them, the rig's structural discrepancy and the terminals' heat path:
  ``docs/gap.md`` method item 11),
* the verdict model alone on the plain baseline (the export before it carried either), and
* the defaults.

Printed per dataset: what the export carried beyond the verdict (a structural discrepancy, the
terminals' heat path), the median replay error per recording of each model, in the tilt and,
through the thermistor lag fitted with it, in the springs' temperatures; over the datasets
where it carried something, the paired ratio export / verdict only (median, range, how often
worse). The export is the rig as it is now: where a draft started during the session, only the
recordings after its onset are replayed (the independent rig's truth says which).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import wilcoxon

from neck_env.gap import diagnose as D
from neck_env.gap import report as R
from neck_env.gap.independent import CONVECTION_LAWS
from neck_env.gap.replay import replay, report_offset_deg, report_thermistor_lag_s
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


def as_now(truth: dict) -> list[bool]:
    """Which recordings of a generated dataset hold the rig as it was at its last recording:
    the export is the rig as it is now (a draft seen to start blows in it), so recordings from
    before a draft's onset (the independent rig's per-recording ``h_multiplier``) would measure
    the draft's absence, not the export. The third rig's truth does not say: all of them."""
    h = [r.get("h_multiplier") for r in truth["recordings"]]
    return [x is None or x == h[-1] for x in h]


def run_seed(a: argparse.Namespace, seed: int, root: Path) -> dict:
    done = root / f"result_{seed}.json"
    if a.resume and done.exists():
        return json.loads(done.read_text())
    seen, unseen = root / f"ds_{seed}", root / f"ds_{seed}_drawn"
    truth = generate(a.generator, seen, seed, "mixed", a.effects, a.convection)
    later = generate(a.generator, unseen, seed, "drawn", a.effects, a.convection)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        dg = D.diagnose(read_dataset(seen), still_air=a.still_air)
        rep = R.write_outputs(dg, root / f"report_{seed}.json", seen, make_plots=False)
    seconds = time.perf_counter() - t0
    effects = json.loads(Path(rep["outputs"]["effects"]).read_text())
    verdict_only = dg.model.params_of(dg.final.values)
    off, lag = report_offset_deg(rep), report_thermistor_lag_s(rep)
    own = R.sensors_of(dg.final.setting())  # the verdict model's own sensor fit
    off_v, lag_v = (own["offset_x_deg"], own["offset_y_deg"]), own["thermistor_lag_s"]
    recs = read_dataset(unseen).recordings
    recs = [r for r, now in zip(recs, as_now(later)) if now]
    runs = {"exported": [replay(r, rep["outputs"]["params"], effects, off, lag) for r in recs],
            "verdict_only": [replay(r, verdict_only, effects, off_v, lag_v) for r in recs],
            "defaults": [replay(r, None, None, (0.0, 0.0), lag) for r in recs]}
    out = {"seed": seed, "truth": truth["effects"], "verdict": rep["verdict"],
           "replayed": [r.name for r in recs],
           "export": rep["export"], "seconds": seconds,
           **{f"{k}_deg": [x["tilt_deg"] for x in v] for k, v in runs.items()},
           **{f"{k}_C": [x["temperature_C"] for x in v] for k, v in runs.items()}}
    done.write_text(json.dumps(out, indent=1))
    return out


def _carried(x: dict) -> str:
    parts = []
    if x.get("structure") is not None:
        parts.append(f"{x['structure']} " + ", ".join(f"{k} {v:.3g}" for k, v in x["params"].items()))
    if x.get("terminals") is not None:
        parts.append(f"terminals {x['terminals']['terminal_share']:.2f}")
    return "; ".join(parts) if parts and x["exported"] else "none"


def summarize(results: list[dict]) -> str:
    L = [f"{'seed':>6s} {'verdict':22s} {'carried beyond the verdict':34s} "
         f"{'tilt (deg): export':>18s} {'verdict only':>12s} {'defaults':>8s} "
         f"{'T (C): export':>13s} {'verdict only':>12s} {'defaults':>8s}   (medians per recording)"]
    med = {}
    for r in results:
        m = {k: float(np.median(r[k])) for k in ("exported_deg", "verdict_only_deg", "defaults_deg")}
        m.update({k: float(np.median(r[k])) if r[k] and r[k][0] is not None else math.nan
                  for k in ("exported_C", "verdict_only_C", "defaults_C")})
        med[r["seed"]] = m
        L.append(f"{r['seed']:>6d} {','.join(r['verdict']) or '-':22s} {_carried(r['export']):34s} "
                 f"{m['exported_deg']:18.3f} {m['verdict_only_deg']:12.3f} {m['defaults_deg']:8.3f} "
                 f"{m['exported_C']:13.2f} {m['verdict_only_C']:12.2f} {m['defaults_C']:8.2f}")
    n = len(results)
    carried = [r["seed"] for r in results if _carried(r["export"]) != "none"]
    L.append(f"carried beyond the verdict on {len(carried)}/{n} datasets")
    for unit, k in (("tilt", "deg"), ("temperatures", "C")):
        pairs = [(med[s][f"exported_{k}"], med[s][f"verdict_only_{k}"]) for s in carried
                 if math.isfinite(med[s][f"exported_{k}"])]
        if not pairs:
            continue
        q = [e / v for e, v in pairs]
        L.append(f"  {unit}: replay error export / verdict only, median ratio {statistics.median(q):.3f} "
                 f"(range {min(q):.3f}-{max(q):.3f}); worse on {sum(e > v for e, v in pairs)}/{len(pairs)}"
                 + (f"; paired Wilcoxon p = {wilcoxon([e for e, _ in pairs], [v for _, v in pairs]).pvalue:.3g}"
                    if len(pairs) >= 6 else ""))
    L.append(f"over all {n}: median of the per-dataset medians, tilt export "
             f"{statistics.median(m['exported_deg'] for m in med.values()):.3f} deg against the "
             f"defaults' {statistics.median(m['defaults_deg'] for m in med.values()):.3f} deg; "
             f"diagnosis {statistics.median(r['seconds'] for r in results):.0f} s per dataset (median)")
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generator", choices=GENERATORS, default="independent")
    ap.add_argument("--first-seed", type=int, default=12300)
    ap.add_argument("--datasets", type=int, default=8)
    ap.add_argument("--effects", default="", help="comma-separated effects every rig holds (default none)")
    ap.add_argument("--convection", default="constant", choices=tuple(CONVECTION_LAWS),
                    help="the independent rig's springs: a constant h, or still air's laws")
    ap.add_argument("--still-air", action="store_true", help="diagnose with neck-gap --still-air")
    ap.add_argument("--out", type=Path, default=Path("runs/gap_export"))
    ap.add_argument("--resume", action="store_true", help="keep the seeds already done in --out")
    ap.add_argument("--summarize", action="store_true", help="print the results in --out only")
    a = ap.parse_args(argv)
    a.effects = [e for e in a.effects.split(",") if e]
    if a.convection != "constant" and a.generator != "independent":
        ap.error("--convection is the independent rig's (the third rig's springs have their own law)")
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
