"""Command line of the diagnosis: ``python -m neck_env.gap DATASET_DIR --json REPORT.json``
(console script ``neck-gap``).

Exit codes: 0 done (whatever the verdict), 2 bad input (the message names the file and line;
nothing is written), 1 an unexpected failure (nothing is written either: the JSON report is
written last, and only when everything before it succeeded).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from ..recording import (Dataset, RecordingError, add_wire_arguments, gap_span_s, read_dataset,
                         runs, wire_from_arguments)

# A failed I2C read leaves a row without its IMU reading; over half a second the neck (a few
# deg/s at most) moves along a line well inside the sensor's noise, so such gaps are filled.
IMU_GAP_MAX_S = 0.5


def imu_gaps_filled(ds: Dataset) -> list[dict]:
    """Per recording with filled IMU readings (``Recording.imu_filled``): how many, and the
    longest gap between the readings around a run of them, s."""
    out = []
    for r in ds.recordings:
        m = r.imu_filled
        if m is None or not m.any():
            continue
        longest = max(gap_span_s(r.t, a, b) for a, b in runs(m))
        out.append({"recording": r.name, "samples": int(m.sum()), "longest_gap_s": longest})
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="neck-gap",
        description="Sim-to-real gap diagnosis of a dataset of neck recordings: calibrates the "
                    "nominal model, localizes the residual, attributes it to catalogued "
                    "unmodelled effects on held-out recordings and exports the corrected model.")
    ap.add_argument("dataset", help="folder of recordings (*.csv, optional meta.json)")
    ap.add_argument("--json", required=True, metavar="REPORT.json",
                    help="report to write; plots, REPORT_params.json and REPORT_effects.json "
                         "go beside it")
    ap.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    ap.add_argument("--quiet", action="store_true", help="print only the verdict line")
    ap.add_argument("--fit-spring-modulus", action="store_true",
                    help="also fit the springs' martensite modulus (x0.25-5) as part of the "
                         "rig's baseline: for springs not wound or drawn as the paper's "
                         "(docs/gap.md, 'Springs not the paper's')")
    ap.add_argument("--fit-terminals", action="store_true",
                    help="also fit the heat the springs drain into their terminals (crimps, "
                         "posts: a second, slower thermal mass) as part of the rig's baseline: "
                         "for springs crimped to metal, when h must be the air's alone "
                         "(docs/gap.md, 'Heat drained into the terminals')")
    ap.add_argument("--still-air", action="store_true",
                    help="the rig's springs cool in still air (no fan, no draft): free "
                         "convection (h ~ dT^n, n up to 1/3) is a structural rival that a "
                         "convection change must beat (docs/gap.md, 'Springs in still air')")
    ap.add_argument("--imu-gap-max-s", type=float, default=IMU_GAP_MAX_S, metavar="S",
                    help="fill missing theta_deg/phi_deg readings (empty or nan cells: a failed "
                         "IMU read) from their neighbours over gaps of at most S seconds; "
                         "longer ones are an error; 0 refuses any (default %(default)g; "
                         "the report's \"imu_gaps_filled\" lists them)")
    add_wire_arguments(ap)
    args = ap.parse_args(argv)
    if not args.imu_gap_max_s >= 0:  # also NaN
        print(f"neck-gap: bad input: --imu-gap-max-s {args.imu_gap_max_s} must be >= 0 s",
              file=sys.stderr)
        return 2
    try:
        wire = wire_from_arguments(args)
    except ValueError as exc:
        print(f"neck-gap: bad input: {exc}", file=sys.stderr)
        return 2

    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    try:
        ds = read_dataset(args.dataset, imu_gap_max_s=args.imu_gap_max_s)
    except RecordingError as exc:
        print(f"neck-gap: bad input: {exc}", file=sys.stderr)
        return 2
    filled = imu_gaps_filled(ds)
    for f in filled:
        print(f"neck-gap: warning: {f['recording']}: {f['samples']} missing IMU reading(s) "
              f"filled from their neighbours (longest gap {f['longest_gap_s']:.3g} s)",
              file=sys.stderr)
    ds.meta.update(wire)  # the command line over meta.json; the folder is not written
    from .diagnose import diagnose
    from .report import text_report, write_outputs
    from .rest import not_at_rest, without

    # recordings that do not start at rest would inflate the gap: out, with a warning
    bent = not_at_rest(ds)
    for b in bent:
        print(f"neck-gap: warning: {b['recording']} does not start at rest ({b['why']}): "
              f"excluded", file=sys.stderr)
    if bent and len(bent) == len(ds.recordings):
        print("neck-gap: bad input: no recording starts at rest (record each one from an "
              "upright neck with cold springs: python -m neck_env.rig protocol waits for that)",
              file=sys.stderr)
        return 2
    try:
        dg = diagnose(without(ds, [b["recording"] for b in bent]), log=log,
                      spring_modulus=args.fit_spring_modulus, terminals=args.fit_terminals,
                      still_air=args.still_air)
        rep = write_outputs(dg, args.json, dataset_path=Path(args.dataset),
                            make_plots=not args.no_plots, extra={"not_at_rest": bent,
                                                             "imu_gaps_filled": filled})
    except RecordingError as exc:
        print(f"neck-gap: bad input: {exc}", file=sys.stderr)
        return 2
    if args.quiet:
        print(f"verdict: {', '.join(rep['verdict']) or 'none'}; unexplained: {rep['unexplained']}")
    else:
        print(text_report(rep))
    if bent:
        print(f"EXCLUDED {len(bent)} recording(s) that do not start at rest: "
              f"{', '.join(b['recording'] for b in bent)} (see \"not_at_rest\" in {args.json})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
