"""The rig workflow without hardware, at full size: the whole ``rig`` protocol recorded on
emulated rigs, then ``neck-gap`` -- what a user gets from the README's "Try the rig without
hardware".

    python benchmarks/rig_protocol.py                       # the protocol of the README
    python benchmarks/rig_protocol.py --effects none        # one rig only
    python benchmarks/rig_protocol.py --recordings 4 --duration 12 --protocol mixed   # quick

For each case, an emulated rig (``python -m neck_env.rig emulate``: the firmware in simavr,
the simulator as the neck, in real time) and ``python -m neck_env.rig protocol`` against it,
all cases in parallel (each rig runs in real time; they share nothing). Printed per case: the
wall time of the recording session (and how much of it was waiting for rest), the verdict,
``unexplained``, the held-out gaps before and after the best effect, and any recording
``neck-gap`` found not at rest. Real time is the floor: the full ``rig`` protocol is ~10 min of
recording plus ~1-2 min of cooling after each heated recording (measured on a quiet 2-core
machine, both cases at once, the 18-recording protocol with its reference pulse and the
colder start of its reference and long tails: 28.7 min per session, 18.6 min of it waiting for
rest). Keep the machine otherwise idle: under two more
busy processes the rig link timed out (no reply to a command within 0.5 s) and resumed.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = {"imu_misalignment": '{"imu_misalignment": {"yaw_deg": 12, "tilt_deg": 1}}',
         "none": None}


def _env() -> dict:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(ROOT) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def start_emulator(effects: str | None, seed: int, log: Path) -> tuple[subprocess.Popen, str, str]:
    cmd = [sys.executable, "-m", "neck_env.rig", "emulate", "--seed", str(seed)]
    if effects:
        cmd += ["--effects", effects]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env=_env())
    port = supply = None
    lines = []
    while port is None or supply is None:
        line = p.stdout.readline()
        if not line:
            raise SystemExit("emulate failed:\n" + "".join(lines))
        lines.append(line)
        port = port or (m.group(1) if (m := re.match(r"port: (\S+)", line)) else None)
        supply = supply or (m.group(1) if (m := re.search(r"echo AMPS > (\S+)", line)) else None)
    log.write_text("".join(lines))
    return p, port, supply


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", choices=[*CASES, "both"], default="both")
    ap.add_argument("--protocol", default="rig")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--recordings", type=int, default=None)
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--resumes", type=int, default=3,
                    help="rerun (resume) a session that stopped on an error at most this often")
    ap.add_argument("--out", default=None, help="folder for datasets and reports (default: temp)")
    args = ap.parse_args()
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="rig_protocol_"))
    root.mkdir(parents=True, exist_ok=True)
    names = list(CASES) if args.effects == "both" else [args.effects]
    extra = (["--recordings", str(args.recordings)] if args.recordings else []) + \
            (["--duration", str(args.duration)] if args.duration else [])
    emus, runs, t0 = {}, {}, {}
    try:
        for i, n in enumerate(names):
            emus[n] = start_emulator(CASES[n], 10 + i, root / f"{n}_emulate.log")
        def start(n: str) -> subprocess.Popen:
            _, port, supply = emus[n]
            return subprocess.Popen(
                [sys.executable, "-m", "neck_env.rig", "protocol", "--port", port,
                 "--record", str(root / n), "--protocol", args.protocol, "--seed",
                 str(args.seed), *extra, "--supply-cmd", f"echo {{amps}} > {supply}"],
                stdout=open(root / f"{n}_protocol.log", "a"), stderr=subprocess.STDOUT, env=_env())

        for n in names:
            t0[n] = time.monotonic()
            runs[n] = start(n)
        took, resumed = {}, {n: 0 for n in names}
        pending = set(names)
        while pending:
            time.sleep(1.0)
            for n in sorted(pending):
                if runs[n].poll() is None:
                    continue
                # an error (e.g. a missed reply on a loaded machine) stops the session with the
                # relays off; a user runs the same command again and it resumes
                if runs[n].returncode != 0 and resumed[n] < args.resumes:
                    resumed[n] += 1
                    runs[n] = start(n)
                    continue
                pending.discard(n)
                took[n] = time.monotonic() - t0[n]
                if runs[n].returncode != 0:
                    raise SystemExit(f"{n}: protocol failed, see {root / f'{n}_protocol.log'}")
    finally:
        for p in runs.values():
            if p.poll() is None:
                p.kill()
        for p, _, _ in emus.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(10)
    print(f"datasets and logs in {root}")
    for n in names:
        log = (root / f"{n}_protocol.log").read_text()
        waits = sum(float(w) for w in re.findall(r"after (\d+) s at rest wait", log)) / 60
        t = time.monotonic()
        rep_path = root / f"{n}_report.json"
        subprocess.run([sys.executable, "-m", "neck_env.gap", str(root / n), "--json",
                        str(rep_path), "--quiet", "--no-plots"], env=_env(), check=True)
        gap_s = time.monotonic() - t
        rep = json.loads(rep_path.read_text())
        best = rep["effects"][0]
        print(f"{n:18s} recording {took[n] / 60:5.1f} min ({waits:.1f} min waiting for rest, "
              f"{resumed[n]} resume(s) after an error), neck-gap {gap_s:4.0f} s: verdict {rep['verdict'] or '[]'}, unexplained "
              f"{rep['unexplained']}, held-out gap {best['heldout_gap_before']:.3f} -> "
              f"{best['heldout_gap_after']:.3f} deg ({best['name']}), not at rest: "
              f"{[b['recording'] for b in rep.get('not_at_rest', [])] or 'none'}")


if __name__ == "__main__":
    main()
