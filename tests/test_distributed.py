"""Scaling out on Ray: fan-out, sweep, and a real two-node cluster on this machine.

The cluster tests start separate ``ray start`` processes (head + nodes of one CPU each, loopback
addresses, free ports, their own temp folder), drive them through the commands' ``--ray`` /
``--address`` options in subprocesses as a user would, compare with a local run, and stop every
node in teardown. They are skipped only when Ray is not installed (CI installs it).
"""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from agents.distributed import LOCAL, LocalCluster, fan_out

# one worker holds this module's Ray clusters (the module-scoped one is started once)
pytestmark = pytest.mark.xdist_group("ray")

ROOT = Path(__file__).resolve().parents[1]
HAS_RAY = importlib.util.find_spec("ray") is not None
requires_ray = pytest.mark.skipif(
    not HAS_RAY, reason="Ray is not installed (pip install -e '.[sweep]'; CI installs it)")
TINY_DATA = ["--recordings", "3", "--duration", "10"]  # a dataset diagnosed in ~1 s


def _diagnosis(report: dict) -> dict:
    """What a diagnosis concluded: the split, the verdict, ``unexplained`` and every held-out
    gap by name (effects by name, not rank: near-ties on a tiny dataset may swap places)."""
    return {"split": (report["recordings"], report["heldout_recordings"]),
            "verdict": report["verdict"], "unexplained": report["unexplained"],
            "nominal": report["nominal"]["heldout_gap"],
            "effects": {e["name"]: e["heldout_gap_after"] for e in report["effects"]},
            "structure": {e["name"]: e["heldout_gap_after"] for e in report["structure"]}}


def _assert_same_diagnosis(a: dict, b: dict, abs_deg: float = 1e-3) -> None:
    """The same conclusions and held-out gaps to ``abs_deg``: Ray's workers run BLAS on one
    thread (OMP_NUM_THREADS=1), which reorders sums; the last digits move, and through the
    fits' stopping rules a gap can move by ~1e-5 deg."""
    da, db = _diagnosis(a), _diagnosis(b)
    for k in ("split", "verdict", "unexplained"):
        assert da[k] == db[k], f"{k}: {da[k]!r} != {db[k]!r}"
    assert da["nominal"] == pytest.approx(db["nominal"], abs=abs_deg)
    for k in ("effects", "structure"):
        assert da[k].keys() == db[k].keys()
        for name in da[k]:
            assert da[k][name] == pytest.approx(db[k][name], abs=abs_deg), (k, name)


def _square(x: int) -> int:
    if x == 3:
        raise ValueError("three is not allowed")
    return x * x


# --- without Ray -------------------------------------------------------------------------

def test_library_and_local_runs_do_not_import_ray():
    code = ("import sys, neck_env, neck_env.envs, neck_env.gap.cli, agents.benchmark, "
            "agents.distributed, agents.sweep; "
            "assert 'ray' not in sys.modules, 'ray imported'; print('ok')")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0 and "ok" in res.stdout, res.stderr[-2000:]


def test_asking_for_ray_without_it_says_how_to_install():
    code = ("import sys; sys.modules['ray'] = None\n"
            "from agents.benchmark import main\n"
            "main(['--quick', '--controllers', 'zero', '--ray'])")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode != 0
    assert "Ray is not installed" in res.stderr and ".[sweep]" in res.stderr


def test_local_fan_out_keeps_order_and_reports_a_failing_item():
    seen = []
    out = fan_out(_square, [1, 2, 3, 4], None, progress=lambda o, k, n: seen.append((o.index, k, n)))
    assert [o.value for o in out] == [1, 4, None, 16]
    assert out[2].error.startswith("ValueError: three is not allowed")
    assert all(o.node_id == LOCAL for o in out)
    assert seen == [(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 4, 4)]


def test_sweep_file_errors_name_the_problem(tmp_path):
    from agents.sweep import load_spec

    bad = tmp_path / "bad.yml"
    bad.write_text("algo: ppo\nsearch_space:\n  learning_rate: {lognormal: [1, 2]}\n")
    with pytest.raises(SystemExit, match="search_space.learning_rate"):
        load_spec(bad)
    bad.write_text("algo: ppo\nsearch_space: {gamma: {uniform: [0.9, 0.99]}}\nseedz: [1]\n")
    with pytest.raises(SystemExit, match="unknown key.*seedz"):
        load_spec(bad)
    spec = load_spec(ROOT / "agents" / "sweeps" / "ppo.yml")
    assert spec.base_cfg["n_envs"] == 16 and spec.seeds == (0, 1)  # override over ppo.yml


# --- on a two-node cluster -----------------------------------------------------------------

@pytest.fixture(scope="module")
def cluster():
    if not HAS_RAY:
        pytest.skip("Ray is not installed (pip install -e '.[sweep]'; CI installs it)")
    # a short folder of its own: under pytest-xdist tmp_path grows a worker level, and the
    # nodes' socket paths under it would pass a Unix socket's 107 bytes
    temp = tempfile.mkdtemp(prefix="neck-ray-", dir="/tmp" if os.path.isdir("/tmp") else None)
    c = LocalCluster(temp)
    try:
        c.add_node(num_cpus=1)  # head
        c.add_node(num_cpus=1)
        yield c
    finally:
        c.stop()
        shutil.rmtree(temp, ignore_errors=True)


def test_a_cluster_folder_too_long_for_rays_sockets_is_refused_before_any_node_starts(tmp_path):
    deep = tmp_path / ("x" * 60)
    with pytest.raises(ValueError, match="107-byte limit of a Unix socket"):
        LocalCluster(deep)
    LocalCluster("/tmp/neck-ray")  # a short one is taken


def _run(cmd: list[str], cluster: LocalCluster, timeout: float = 300) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, *cmd], cwd=ROOT, capture_output=True, text=True,
                         timeout=timeout, env={**os.environ, **cluster.DRIVER_ENV})
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return res


def _tiny_sweep(tmp_path: Path, **extra) -> Path:
    spec = {"algo": "ppo", "base_config": str(ROOT / "agents" / "configs" / "ppo.yml"),
            "overrides": {"n_envs": 8, "n_steps": 256, "batch_size": 512},
            "n_timesteps": 4096, "report_every": 2048, "seeds": [0, 1], "num_samples": 1,
            "max_concurrent": 2, "search_seed": 0,
            "objective": {"episodes": 1, "episode_s": 10.0},
            "search_space": {"learning_rate": {"loguniform": [1e-4, 1e-3]},
                             "gae_lambda": {"uniform": [0.9, 0.99]}}}
    spec.update(extra)
    path = tmp_path / "tiny.yml"
    path.write_text(json.dumps(spec))  # JSON is YAML
    return path


def _rows(path: Path) -> list[dict]:
    with path.open() as f:
        return list(csv.DictReader(f))


@requires_ray
def test_sweep_on_two_nodes_equals_local_training(cluster, tmp_path):
    from agents.sweep import load_spec, train_and_score

    spec_path = _tiny_sweep(tmp_path)
    out = tmp_path / "sweep"
    res = _run(["-m", "agents.sweep", str(spec_path), "--address", cluster.address,
                "--out", str(out), "--ship", str(tmp_path / "shipped" / "best")], cluster)
    rows = _rows(out / "results.csv")
    # ASHA may stop the worse trial at the first rung (2048 steps); the other trains to the end
    assert len(rows) == 2 and {r["status"] for r in rows} <= {"finished", "stopped early"}, rows
    assert all((r["status"] == "finished") == (r["timesteps"] == "4096") for r in rows), rows
    assert any(r["status"] == "finished" for r in rows)
    assert sorted(r["seed"] for r in rows) == ["0", "1"]
    assert len({r["node_id"] for r in rows}) == 2, "both trials ran on the same node"
    assert res.stdout.count("] trial ") == 2  # one progress line per finished trial
    assert (out / "sweep.png").stat().st_size > 10_000
    assert (tmp_path / "shipped" / "best.zip").exists()
    meta = json.loads((tmp_path / "shipped" / "best.json").read_text())
    assert meta["algo"] == "PPO" and meta["trained"]["n_timesteps"] == 4096
    for r in rows:  # a trial's TensorBoard logs: Tune's and SB3's
        trial_dir = out / "trials" / f"trial_{r['trial_id']}"
        assert list(trial_dir.glob("events.out.tfevents.*")) and list((trial_dir / "tb").rglob("events*"))
    # the same configuration and seed trained here, without Ray, scores the same
    r0 = next(r for r in rows if r["seed"] == "0")
    spec = dataclasses.replace(load_spec(spec_path), n_timesteps=int(r0["timesteps"]))
    params = {k[6:]: float(v) for k, v in r0.items() if k.startswith("param.")}
    local = train_and_score(spec, params, 0, lambda m, c: None)
    assert local["timesteps"] == int(r0["timesteps"])
    assert local["rmse_deg"] == float(r0["rmse_deg"])
    assert local["energy_J"] == float(r0["energy_J"])


@requires_ray
def test_gap_blind_on_two_nodes_equals_local(cluster, tmp_path, gap_blind_script):
    gb = gap_blind_script
    _run(["benchmarks/gap_blind.py", "--datasets", "2", *TINY_DATA, "--out", str(tmp_path),
          "--ray", cluster.address], cluster)
    remote = json.loads((tmp_path / "results.json").read_text())
    assert [r["seed"] for r in remote] == [1000, 1001]
    assert len({r["node_id"] for r in remote}) == 2, "both datasets ran on the same node"
    for (effects, seed), r in zip(gb.cases(False)[:2], remote):
        local = gb.run_case(effects, seed, tmp_path / "local", False, n_recordings=3,
                            duration_s=10.0)
        assert local["rc"] == r["rc"] == 0
        assert local["truth"] == r["truth"]
        _assert_same_diagnosis(local["report"], r["report"])


@requires_ray
def test_benchmark_episodes_on_two_nodes_equal_local(cluster, tmp_path):
    from agents.benchmark import main as bench

    args = ["--controllers", "zero,pid", "--episodes", "2", "--episode-s", "5", "--no-plot"]
    res = _run(["-m", "agents.benchmark", *args, "--out-dir", str(tmp_path / "ray"),
                "--ray", cluster.address], cluster)
    bench([*args, "--out-dir", str(tmp_path / "local")])
    nodes = {line.split(" on node ")[1].split()[0] for line in res.stdout.splitlines()
             if " on node " in line}
    assert len(nodes) == 2, res.stdout

    def table(d):
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in _rows(d / "benchmark.csv")]

    assert table(tmp_path / "ray") == table(tmp_path / "local") and len(table(tmp_path / "local")) == 36  # 3 suites x 2 modes x 2 controllers x (2 episodes + all)


@requires_ray
def test_sweep_reports_a_crashing_trial_and_ctrl_c_keeps_finished_ones(cluster, tmp_path):
    # batch_size 1 makes SB3's PPO raise; Optuna (seed 0) proposes it first, then 512.
    spec_path = _tiny_sweep(tmp_path, seeds=[0], num_samples=6, max_concurrent=1,
                            search_space={"batch_size": {"choice": [1, 512]},
                                          "learning_rate": {"loguniform": [1e-4, 1e-3]}})
    out = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, "-m", "agents.sweep", str(spec_path), "--address",
                             cluster.address, "--out", str(out)], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**os.environ, **cluster.DRIVER_ENV})
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if sum(ln.startswith("[") and "] trial " in ln for ln in lines) >= 2:
                proc.send_signal(signal.SIGINT)  # Ctrl-C
                break
        rest, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = "".join(lines) + rest
    assert proc.returncode == 0, text[-3000:]
    rows = _rows(out / "results.csv")
    errors = [r for r in rows if r["status"] == "error"]
    finished = [r for r in rows if r["status"] == "finished"]
    assert errors and all("batch_size" in r["error"] and r["param.batch_size"] == "1" for r in errors)
    assert finished and all(r["param.batch_size"] == "512" and float(r["rmse_deg"]) > 0
                            for r in finished)
    assert sum(r["status"] != "not run" for r in rows) < 6, "Ctrl-C did not stop the sweep"
    assert "error: AssertionError" in text  # the crash's own progress line
    assert (out / "best_policy.zip").exists()


@requires_ray
def test_a_node_dying_mid_run_loses_no_result(cluster, tmp_path):
    """Runs last in this module: it adds a third node and kills it while it works."""
    k = cluster.add_node(num_cpus=1)
    proc = subprocess.Popen([sys.executable, "benchmarks/gap_blind.py", "--datasets", "6",
                             *TINY_DATA, "--out", str(tmp_path), "--ray", cluster.address],
                            cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**os.environ, **cluster.DRIVER_ENV})
    lines, killed = [], False
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("seed "):  # the first dataset is done: the others are running
                cluster.kill_node(k)
                killed = True
                break
        rest, _ = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = "".join(lines) + rest
    assert proc.returncode == 0, text[-3000:]
    assert killed, "the run ended before the node could be killed"
    results = json.loads((tmp_path / "results.json").read_text())
    assert sorted(r["seed"] for r in results) == list(range(1000, 1006))
    assert all(r["rc"] == 0 and r["report"].get("verdict") is not None for r in results)
    assert "failures: 0" in text


def test_sweep_trial_resumes_from_its_checkpoint(tmp_path):
    """What a trial does when its node died: continue from the last checkpoint, not from 0."""
    import shutil

    from agents.sweep import load_spec, train_and_score

    spec = dataclasses.replace(load_spec(_tiny_sweep(tmp_path)), n_timesteps=2048)
    params = {"learning_rate": 3e-4, "gae_lambda": 0.95}
    saved = tmp_path / "ckpt"

    def keep(metrics, ckpt_dir):
        shutil.copytree(ckpt_dir, saved)
        assert (saved / "policy.zip").exists() and (saved / "vecnormalize.pkl").exists()

    first = train_and_score(spec, params, 0, keep)
    reports = []
    resumed = train_and_score(dataclasses.replace(spec, n_timesteps=4096), params, 0,
                              lambda m, c: reports.append(m["timesteps"]), resume_from=saved)
    assert first["timesteps"] == 2048
    assert reports == [4096] and resumed["timesteps"] == 4096  # one chunk: it went on from 2048
