"""Fan independent work out as Ray tasks: on this machine, or on a cluster when asked.

Used by ``agents.benchmark --ray`` (episodes), ``benchmarks/gap_blind.py --ray`` (datasets),
``benchmarks/scale_out.py`` and, for the connection only, ``agents.sweep`` (Ray Tune trials).
Ray is optional (``pip install -e ".[sweep]"``): nothing here imports it until a caller asks for
Ray, and without ``--ray`` the same work runs in this process, one item after the other.

Where it runs (the ``ADDRESS`` of ``--ray [ADDRESS]``):

* no address (``--ray`` alone): an embedded Ray started for this run on this machine, one
  worker per core, stopped at the end;
* ``auto``, ``HOST:PORT`` or ``ray://HOST:10001``: an existing cluster started with
  ``ray start --head`` (and ``ray start --address HOST:PORT`` on every other machine). The
  project's code travels with the job as a Ray runtime environment (``working_dir`` = the
  repository, without ``.git``, ``runs/`` and caches), so workers need only the dependencies
  (``pip install -e ".[sweep]"`` or the same packages), not a checkout.

Failures: an exception raised by the work itself is caught in the worker and reported with the
item (the other items go on); a worker or node that dies is not the item's fault, and Ray runs
the task again elsewhere (``max_retries``), so a finished run holds every item.
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

LOCAL = "local"  # the --ray value meaning "embedded Ray on this machine"
REPO_ROOT = Path(__file__).resolve().parents[1]
# Not shipped to workers: history, outputs and per-machine caches (numba's live in __pycache__).
SHIP_EXCLUDES = [".git", "runs", "**/__pycache__", "*.egg-info", ".pytest_cache", "firmware/build"]
RETRIES_ON_NODE_LOSS = 3
# The embedded Ray binds to loopback only (as Ray does on macOS and Windows), not to the
# machine's network address: nothing outside this machine needs to reach it. Read at import.
LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


@dataclass(frozen=True)
class TaskOutcome:
    """One item's result: ``value`` (None if the work raised, then ``error`` says why), the Ray
    node that ran it (``"local"`` without Ray) and the wall time of the work in the worker."""

    index: int
    value: Any
    error: str | None
    node_id: str
    wall_s: float


def import_ray():
    """The ``ray`` module, or a clear error saying how to get it."""
    try:
        import ray
    except ImportError as exc:  # an optional extra: say which
        raise SystemExit("Ray is not installed: pip install -e \".[sweep]\" (or pip install "
                         "'ray[tune]' optuna)") from exc
    return ray


def add_ray_argument(parser, what: str) -> None:
    """``--ray [ADDRESS]`` with the same meaning on every command."""
    parser.add_argument(
        "--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
        help=f"run the {what} as Ray tasks: alone = an embedded Ray on this machine; 'auto', "
             "HOST:PORT or ray://HOST:10001 = an existing cluster (ray start --head), the "
             "project shipped to its workers as the job's runtime environment")


def runtime_env() -> dict[str, Any]:
    """The repository as the job's ``working_dir``: workers import this checkout's code."""
    return {"working_dir": str(REPO_ROOT), "excludes": list(SHIP_EXCLUDES)}


def connect(address: str | None = LOCAL, worker_logs: bool = True):
    """Start (``LOCAL`` or None) or join (an address) Ray once per process; returns ``ray``.
    ``worker_logs``: show the workers' output here (off when the caller reports results)."""
    import os
    import sys

    if address in (None, LOCAL) and "ray" not in sys.modules:
        for k, v in LOOPBACK_ENV.items():
            os.environ.setdefault(k, v)
    ray = import_ray()
    if ray.is_initialized():
        return ray
    common = {"include_dashboard": False, "log_to_driver": worker_logs,
              "configure_logging": False}
    if address in (None, LOCAL):
        # "local" always starts a fresh instance, even when a cluster runs on this machine.
        ray.init(address="local", **common)
    else:
        ray.init(address=address, runtime_env=runtime_env(), **common)
    return ray


def _run_one(fn: Callable[[Any], Any], item: Any, index: int, node_id: str) -> TaskOutcome:
    t0 = time.perf_counter()
    try:
        value, error = fn(item), None
    except Exception as exc:  # the item's own failure: report it, keep the others going
        value = None
        error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=4)}"
    return TaskOutcome(index, value, error, node_id, time.perf_counter() - t0)


def _remote_one(fn: Callable[[Any], Any], item: Any, index: int) -> TaskOutcome:
    import ray

    ctx = ray.get_runtime_context()
    _threads_to_cpus(ctx.get_assigned_resources().get("CPU", 1.0))
    return _run_one(fn, item, index, ctx.get_node_id())


def _threads_to_cpus(cpus: float) -> None:
    """Numba's thread pool sized to the CPUs Ray gave this task. Ray caps OpenMP's threads
    (OMP_NUM_THREADS) but not numba's, which otherwise starts one per core of the machine: a
    one-CPU task of the batched plant would take every core, oversubscribing a node that runs
    several such tasks."""
    import numba

    numba.set_num_threads(max(1, min(int(cpus), numba.config.NUMBA_NUM_THREADS)))


def fan_out(fn: Callable[[Any], Any], items: Sequence[Any] | Iterable[Any],
            address: str | None = None,
            progress: Callable[[TaskOutcome, int, int], None] | None = None,
            num_cpus: float = 1.0) -> list[TaskOutcome]:
    """``fn(item)`` for every item, in input order.

    ``address`` None: in this process, one after the other (no Ray needed). Otherwise Ray
    tasks (``LOCAL`` = embedded Ray), spread over the nodes, each asking for ``num_cpus``;
    ``progress(outcome, n_done, n_total)`` is called as each finishes (completion order).
    ``fn`` and the items must pickle (module-level functions, ``functools.partial``).
    Ctrl-C cancels the tasks still pending and re-raises."""
    items = list(items)
    n = len(items)
    done: list[TaskOutcome] = []
    if address is None:
        for i, item in enumerate(items):
            done.append(_run_one(fn, item, i, LOCAL))
            if progress:
                progress(done[-1], len(done), n)
        return done
    ray = connect(address)
    task = ray.remote(_remote_one).options(
        num_cpus=num_cpus, max_retries=RETRIES_ON_NODE_LOSS, retry_exceptions=False,
        scheduling_strategy="SPREAD")
    fn_ref = ray.put(fn)
    pending = [task.remote(fn_ref, item, i) for i, item in enumerate(items)]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            done.append(ray.get(ready[0]))
            if progress:
                progress(done[-1], len(done), n)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    return sorted(done, key=lambda o: o.index)


def print_progress(label: Callable[[Any], str], items: Sequence[Any]):
    """A ``progress`` callback printing one line per finished item."""

    def report(o: TaskOutcome, k: int, n: int) -> None:
        where = "" if o.node_id == LOCAL else f" on node {o.node_id[:8]}"
        status = "ok" if o.error is None else "FAILED " + o.error.splitlines()[0]
        print(f"[{k}/{n}] {label(items[o.index])}: {status}{where} ({o.wall_s:.1f} s)", flush=True)

    return report


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


class LocalCluster:
    """A multi-node Ray cluster on this machine, each node its own ``ray start`` process group
    (what ``ray start --head`` / ``ray start --address`` do on separate machines), on loopback
    addresses and free ports, for tests and ``benchmarks/scale_out.py``.

        with LocalCluster(tmp_dir) as c:
            c.add_node(num_cpus=1)          # the head
            c.add_node(num_cpus=1)          # a second node
            ... --ray c.address ...
            c.kill_node(1)                  # a node dies (SIGKILL of its processes)
    """

    # Token authentication on every node and driver (Ray's default once
    # ~/.ray/auth_token exists; stated so that no process guesses differently), fast failure
    # detection (a dead
    # node is declared dead in ~1.5 s instead of ~30 s), no usage reporting.
    DRIVER_ENV = {"RAY_AUTH_MODE": "token"}
    # Ray swaps "127.0.0.1" for the machine's network address (to be reachable from other
    # machines); another loopback address it takes as given, and the cluster stays on loopback.
    NODE_IP = "127.0.0.2"
    NODE_ENV = {**DRIVER_ENV, "RAY_health_check_period_ms": "500",
                "RAY_health_check_failure_threshold": "3", "RAY_health_check_timeout_ms": "500",
                "RAY_USAGE_STATS_ENABLED": "0"}

    # What ``ray start --temp-dir`` appends for a node's object store socket; a Unix socket's
    # path holds at most 107 bytes, and Ray only says so once the node fails to start.
    SOCKET_SUFFIX = "/n00/session_2026-12-06_17-27-55_504394_1234567/sockets/plasma_store"
    SOCKET_PATH_MAX = 107

    def __init__(self, temp_dir: str | Path, start_timeout_s: float = 60.0):
        self.temp_dir = Path(temp_dir).resolve()
        if len(str(self.temp_dir)) + len(self.SOCKET_SUFFIX) > self.SOCKET_PATH_MAX:
            raise ValueError(
                f"temp_dir {self.temp_dir} is {len(str(self.temp_dir))} characters long: the "
                f"Ray nodes' socket paths under it would exceed the {self.SOCKET_PATH_MAX}-byte "
                f"limit of a Unix socket; give a directory of at most "
                f"{self.SOCKET_PATH_MAX - len(self.SOCKET_SUFFIX)} characters (e.g. under /tmp)")
        self.start_timeout_s = start_timeout_s
        self.address: str | None = None
        self.nodes: list[Any] = []  # subprocess.Popen, one per node (None once killed)

    def add_node(self, num_cpus: int = 1) -> int:
        """Start a node (the first is the head); returns its index once it has joined."""
        import os
        import subprocess
        import sys

        k = len(self.nodes)
        head = self.address is None
        if head:
            self._ensure_token()
        port = _free_port()
        cmd = [sys.executable, "-m", "ray.scripts.scripts", "start", "--block",
               "--num-cpus", str(num_cpus), "--node-ip-address", self.NODE_IP,
               "--temp-dir", str(self.temp_dir / f"n{k}"), "--disable-usage-stats"]
        for flag in ("--node-manager-port", "--object-manager-port", "--runtime-env-agent-port",
                     "--dashboard-agent-grpc-port", "--dashboard-agent-listen-port",
                     "--metrics-export-port"):
            cmd += [flag, str(_free_port())]
        if head:
            cmd += ["--head", "--port", str(port), "--include-dashboard", "false",
                    "--ray-client-server-port", str(_free_port())]
        else:
            cmd += ["--address", self.address]
        log = self.temp_dir / f"node{k}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("w") as f:
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT,
                                    start_new_session=True, env={**os.environ, **self.NODE_ENV})
        self.nodes.append(proc)
        t_end = time.monotonic() + self.start_timeout_s
        while "Ray runtime started" not in log.read_text():
            if proc.poll() is not None or time.monotonic() > t_end:
                self.stop()
                raise RuntimeError(f"ray node {k} did not start; its log:\n{log.read_text()[-3000:]}")
            time.sleep(0.2)
        if head:
            self.address = f"{self.NODE_IP}:{port}"
        return k

    def _ensure_token(self) -> None:
        """A token for the cluster's token authentication. ``ray start`` refuses to run
        without one and, unlike ``ray.init``, never makes one, so on a machine that has never
        run Ray (a fresh CI machine) no node would start. Made as Ray's own local clusters
        make it (``ray get-auth-token --generate``: ``~/.ray/auth_token`` when there is none);
        a token the user gave (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``) is used as it is."""
        import os
        import subprocess
        import sys

        if os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH"):
            return
        # stdout is the token itself: never into a log. A Ray without the command (before
        # token authentication) needs no token; any other failure is Ray's to explain when
        # the head then does not start.
        subprocess.run([sys.executable, "-m", "ray.scripts.scripts", "get-auth-token",
                        "--generate"], env={**os.environ, **self.DRIVER_ENV},
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120,
                       check=False)

    def kill_node(self, k: int) -> None:
        """Kill node ``k`` at once (all its processes: raylet, workers), as a crash would."""
        import os
        import signal

        proc = self.nodes[k]
        if proc is not None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
            self.nodes[k] = None

    def stop(self) -> None:
        """Stop every node (workers first, the head last): SIGTERM, then SIGKILL."""
        import os
        import signal

        for k in reversed(range(len(self.nodes))):
            proc = self.nodes[k]
            if proc is None:
                continue
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(timeout=3)
            except (ProcessLookupError, Exception):
                pass
            self.kill_node(k)

    def __enter__(self) -> "LocalCluster":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
