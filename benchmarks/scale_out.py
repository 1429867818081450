"""Wall time of one fixed workload on a Ray cluster of one node, then of two (one CPU each).

    python benchmarks/scale_out.py                      # 8 blind-evaluation datasets
    python benchmarks/scale_out.py --datasets 4 --recordings 6 --duration 20

The workload is the first ``--datasets`` cases of ``benchmarks/gap_blind.py`` (generate a
synthetic dataset, diagnose it), fanned out by ``agents.distributed.fan_out`` exactly as
``gap_blind.py --ray ADDRESS`` does. Each cluster is started here (``LocalCluster``: separate
``ray start`` process groups, loopback, one CPU per node), first warmed up (every node's worker
imports the project and compiles the simulator once, which a long run pays once too), then
timed on the workload, then stopped. Printed: the wall time on each, the speed-up, the load
average of the machine while it ran (other jobs share it), and whether both runs gave the same
diagnoses. Ray's per-node compile/start-up is reported apart from the timed workload.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gap_blind  # noqa: E402  (a sibling script)

from agents.distributed import LocalCluster, connect, fan_out  # noqa: E402

COMPARE_SKIP = ("timing_s", "dataset", "outputs")


def run_on(n_nodes: int, suite: list, run_kwargs: dict, warm: list, tmp: Path) -> dict:
    import ray

    with LocalCluster(tmp / f"cluster{n_nodes}") as cluster:
        t0 = time.perf_counter()
        for _ in range(n_nodes):
            cluster.add_node(num_cpus=1)
        connect(cluster.address, worker_logs=False)  # the project ships as gap_blind --ray's
        try:
            work = partial(gap_blind.run_case_task, root=None, run_kwargs=run_kwargs)
            tiny = partial(gap_blind.run_case_task, root=None,
                           run_kwargs={**run_kwargs, "n_recordings": 2, "duration_s": 5.0})
            t1 = time.perf_counter()
            fan_out(tiny, warm[:n_nodes], cluster.address)  # one per node (SPREAD)
            t2 = time.perf_counter()
            load0 = os.getloadavg()[0]
            outcomes = fan_out(work, suite, cluster.address)
            t3 = time.perf_counter()
            load1 = os.getloadavg()[0]
        finally:
            ray.shutdown()
    bad = [o.error for o in outcomes if o.error]
    if bad:
        raise RuntimeError(f"{len(bad)} dataset(s) failed: {bad[0]}")
    return {"nodes": n_nodes, "start_s": t1 - t0, "warmup_s": t2 - t1, "wall_s": t3 - t2,
            "load": (load0, load1), "nodes_used": len({o.node_id for o in outcomes}),
            "reports": [{k: v for k, v in o.value["report"].items() if k not in COMPARE_SKIP}
                        for o in outcomes],
            "task_s": [o.wall_s for o in outcomes],
            # what the busiest node spent inside the tasks: the wall time a perfect fan-out
            # would take given how fast the tasks ran (other jobs on the machine slow them)
            "busiest_node_s": max(sum(o.wall_s for o in outcomes if o.node_id == n)
                                  for n in {o.node_id for o in outcomes})}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", type=int, default=8, help="datasets in the workload")
    ap.add_argument("--recordings", type=int, default=None, help="recordings per dataset")
    ap.add_argument("--duration", type=float, default=None, help="seconds per recording")
    args = ap.parse_args(argv)
    os.environ.update(LocalCluster.DRIVER_ENV)  # before Ray is imported
    import ray.cloudpickle

    ray.cloudpickle.register_pickle_by_value(gap_blind)  # workers have no benchmarks/ on sys.path
    cases = gap_blind.cases(False)
    suite, warm = cases[:args.datasets], cases[-2:]
    gen = {k: v for k, v in (("n_recordings", args.recordings), ("duration_s", args.duration))
           if v is not None}
    run_kwargs = {"hard": False, **gen}
    print(f"workload: {len(suite)} blind-evaluation datasets (seeds {suite[0][1]}..{suite[-1][1]}"
          f"{', ' + str(gen) if gen else ', generator defaults'}); machine: {os.cpu_count()} "
          f"cores, load average {os.getloadavg()[0]:.2f} before", flush=True)
    runs = []
    with tempfile.TemporaryDirectory(prefix="scale_out_") as tmp:
        for n in (1, 2):
            r = run_on(n, suite, run_kwargs, warm, Path(tmp))
            runs.append(r)
            print(f"{n} node(s) x 1 CPU: {r['wall_s']:.1f} s for the workload (nodes used "
                  f"{r['nodes_used']}; per dataset median {statistics.median(r['task_s']):.1f} s; "
                  f"cluster start {r['start_s']:.1f} s, warm-up {r['warmup_s']:.1f} s; load "
                  f"average {r['load'][0]:.2f} -> {r['load'][1]:.2f}); the busiest node spent "
                  f"{r['busiest_node_s']:.1f} s in tasks, so the fan-out itself cost "
                  f"{r['wall_s'] - r['busiest_node_s']:.1f} s", flush=True)
    one, two = runs
    same = one["reports"] == two["reports"]
    print(f"speed-up on two nodes: {one['wall_s'] / two['wall_s']:.2f}x (target >= 1.7x); "
          f"per-dataset time {statistics.median(two['task_s']) / statistics.median(one['task_s']):.2f}x "
          f"the one-node run's (above 1: the two nodes' CPUs were not free); diagnoses identical "
          f"on one and two nodes: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
