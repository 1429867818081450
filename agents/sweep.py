"""Hyperparameter sweep of train.py's configs with Ray Tune (Optuna search, ASHA early stopping).

    python -m agents.sweep agents/sweeps/ppo.yml                    # embedded Ray, this machine
    python -m agents.sweep agents/sweeps/ppo.yml --address auto     # a cluster (ray start --head)
    python -m agents.sweep agents/sweeps/ppo.yml --ship agents/policies/ppo_sweep

The sweep file (``agents/sweeps/*.yml``, beside the hyperparameter files) names the base config
(``agents/configs/<algo>.yml``), fixed overrides, the search space, the seeds and the budget.
Each sampled configuration trains once per seed (seeds are a grid axis: Ray Tune's ``Repeater``
gives each sample to ``len(seeds)`` trials, and Optuna learns from their mean). A trial trains
in chunks of ``report_every`` steps; after each it exports the policy, runs the benchmark suite
of ``agents.benchmark`` on it (the objective: tracking RMSE under the energy budget, lower is
better), checkpoints (model, VecNormalize, deployable policy) and reports, and ASHA stops the
trials whose RMSE is behind the others' at the same step count.

Outputs in ``--out`` (default ``runs/sweeps/<name>``): one folder per trial (Ray Tune's
``result.json``/``progress.csv``, TensorBoard logs of Tune and of SB3 in ``tb/``, checkpoints),
``results.csv`` (one row per trial: status, seed, sampled values, steps, RMSE, energy, node,
error), ``sweep.png`` (RMSE against steps per trial, final RMSE per configuration) and
``best_policy.zip`` + ``.json`` (the best trial's policy; ``--ship PATH`` copies it there too).

A trial whose code raises (a bad hyperparameter, NaN in the loss) is reported with its error
and the sweep goes on; a trial whose worker or node dies is restarted from its last checkpoint
(``--max-failures``). Ctrl-C stops the sweep; finished trials are kept and written out.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import yaml

from .distributed import LOCAL, connect, import_ray
from .training import ALGOS, load_config, resolve_config, vecnormalize_of

METRIC = "rmse_deg"
DISTRIBUTIONS = ("loguniform", "uniform", "randint", "choice")
RESULT_COLUMNS = ("trial_id", "status", "seed", "timesteps", "rmse_deg", "energy_J",
                  "within_2deg_frac", "budget_exhausted", "node_id", "wall_s", "error")


@dataclass(frozen=True)
class Objective:
    """The benchmark suite a policy is scored on (``agents.benchmark``'s, shortened)."""

    episodes: int = 2
    episode_s: float = 30.0
    seed: int = 1000
    energy_budget_J: float = 1500.0


@dataclass(frozen=True)
class SweepSpec:
    name: str
    algo: str
    env_id: str
    base_cfg: dict[str, Any]          # the base config block with the overrides applied
    space: dict[str, dict[str, Any]]  # parameter -> {distribution: args, "format": optional}
    seeds: tuple[int, ...]
    n_timesteps: int
    report_every: int
    num_samples: int
    max_concurrent: int
    search_seed: int
    objective: Objective
    grace_period: int
    reduction_factor: float
    source: str = ""


def load_spec(path: Path, overrides: dict[str, Any] | None = None) -> SweepSpec:
    """Read and check a sweep file; ``overrides`` replace its top-level keys (the CLI's)."""
    if not path.exists():
        raise SystemExit(f"sweep file {path} not found")
    raw = yaml.safe_load(path.read_text()) or {}
    raw.update({k: v for k, v in (overrides or {}).items() if v is not None})
    known = {"algo", "env", "base_config", "overrides", "n_timesteps", "report_every", "seeds",
             "num_samples", "max_concurrent", "search_seed", "objective", "asha", "search_space"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise SystemExit(f"{path}: unknown key(s) {unknown}; known: {sorted(known)}")
    algo = str(raw.get("algo", "ppo"))
    if algo not in ALGOS:
        raise SystemExit(f"{path}: algo {algo!r} is not one of {ALGOS}")
    env_id = str(raw.get("env", "NeckTrack-v0"))
    base_path = (path.parent / raw["base_config"]) if "base_config" in raw else (
        Path(__file__).parent / "configs" / f"{algo}.yml")
    cfg = load_config(base_path.resolve(), env_id)
    cfg.update(raw.get("overrides") or {})
    space = raw.get("search_space") or {}
    if not space:
        raise SystemExit(f"{path}: empty search_space")
    for key, dist in space.items():
        kinds = [k for k in dist if k in DISTRIBUTIONS] if isinstance(dist, dict) else []
        extra = [k for k in dist if k not in DISTRIBUTIONS + ("format",)] if isinstance(dist, dict) else []
        if len(kinds) != 1 or extra:
            raise SystemExit(f"{path}: search_space.{key} must be one of {DISTRIBUTIONS} "
                             f"(plus an optional format), got {dist!r}")
        args = dist[kinds[0]]
        if not isinstance(args, list) or (kinds[0] != "choice" and len(args) != 2) or not args:
            raise SystemExit(f"{path}: search_space.{key}.{kinds[0]} needs "
                             + ("a list of values" if kinds[0] == "choice" else "[low, high]"))
    seeds = tuple(int(s) for s in raw.get("seeds", [0]))
    if not seeds or len(set(seeds)) != len(seeds):
        raise SystemExit(f"{path}: seeds must be a non-empty list of distinct integers")
    n_timesteps = int(float(raw.get("n_timesteps", cfg["n_timesteps"])))
    report_every = int(float(raw.get("report_every", n_timesteps)))
    if not 0 < report_every <= n_timesteps:
        raise SystemExit(f"{path}: need 0 < report_every <= n_timesteps")
    asha = raw.get("asha") or {}
    return SweepSpec(
        name=path.stem, algo=algo, env_id=env_id, base_cfg=cfg, space=space, seeds=seeds,
        n_timesteps=n_timesteps, report_every=report_every,
        num_samples=int(raw.get("num_samples", 4)), max_concurrent=int(raw.get("max_concurrent", 2)),
        search_seed=int(raw.get("search_seed", 0)), objective=Objective(**(raw.get("objective") or {})),
        # ASHA may stop a trial after grace_period steps (at most the whole run)
        grace_period=min(int(float(asha.get("grace_period", report_every))), n_timesteps),
        reduction_factor=float(asha.get("reduction_factor", 2)), source=str(path))


def tune_space(spec: SweepSpec) -> dict[str, Any]:
    from ray import tune

    out = {}
    for key, dist in spec.space.items():
        kind = next(k for k in dist if k in DISTRIBUTIONS)
        args = dist[kind]
        if kind == "choice":
            out[key] = tune.choice(list(args))
        else:
            lo, hi = (float(a) for a in args) if kind != "randint" else (int(a) for a in args)
            out[key] = {"loguniform": tune.loguniform, "uniform": tune.uniform,
                        "randint": tune.randint}[kind](lo, hi)
    return out


def trial_config(spec: SweepSpec, params: dict[str, Any]) -> dict[str, Any]:
    """The base config with one sample applied (``format`` turns a number into zoo syntax)."""
    cfg = dict(spec.base_cfg)
    for key, value in params.items():
        if key.startswith("__"):
            continue
        fmt = spec.space.get(key, {}).get("format")
        cfg[key] = fmt.format(value) if fmt else value
    cfg["n_timesteps"] = spec.n_timesteps
    return cfg


def score_policy(policy_zip: Path, objective: Objective) -> dict[str, float]:
    """The benchmark's aggregate row for a deployable policy on the objective's suite."""
    from neck_env.envs import NeckTrackEnv

    from .benchmark import aggregate, policy_agent, run_episode, suite_env_kwargs

    agent = policy_agent(policy_zip, suite_env_kwargs(objective.episode_s, objective.energy_budget_J,
                                                      "current"))
    env = NeckTrackEnv(**agent.env_kwargs)
    rows = [run_episode(agent, env, objective.seed + i).row() for i in range(objective.episodes)]
    agg = aggregate(rows)
    return {k: float(agg[k]) for k in ("rmse_deg", "energy_J", "within_2deg_frac",
                                       "budget_exhausted")}


def train_and_score(spec: SweepSpec, params: dict[str, Any], seed: int,
                    report: Callable[[dict[str, Any], Path], None], trial_dir: Path | None = None,
                    resume_from: Path | None = None) -> dict[str, Any]:
    """Train one trial in chunks; after each, export + score + ``report(metrics, ckpt_dir)``.

    Runs without Ray too (the test compares a Ray trial against this). ``resume_from``: a
    checkpoint folder of this trial (after its worker died) to continue from."""
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    from .policy import export

    torch.set_num_threads(1)
    run = resolve_config(trial_config(spec, params))
    from .training import build_model

    model, env = build_model(spec.algo, run, seed, trial_dir / "tb" if trial_dir else None)
    if resume_from is not None:
        import stable_baselines3 as sb3

        model = getattr(sb3, spec.algo.upper()).load(str(resume_from / "model.zip"), env=env,
                                                     device="cpu")
        vn = vecnormalize_of(env, run)
        if vn is not None:
            saved = VecNormalize.load(str(resume_from / "vecnormalize.pkl"), vn.venv)
            vn.obs_rms, vn.ret_rms = saved.obs_rms, saved.ret_rms
    trained = {"sweep": spec.source, "seed": seed, "params": {k: v for k, v in params.items()
                                                             if not k.startswith("__")}}
    metrics: dict[str, Any] = {}
    started = time.perf_counter()
    while model.num_timesteps < spec.n_timesteps:
        chunk = min(spec.report_every, spec.n_timesteps - model.num_timesteps)
        model.learn(total_timesteps=chunk, reset_num_timesteps=False, tb_log_name=spec.algo)
        with tempfile.TemporaryDirectory(prefix="ckpt_") as tmp:
            ckpt = Path(tmp)
            model.save(str(ckpt / "model.zip"))
            vn = vecnormalize_of(env, run)
            if vn is not None:
                vn.save(str(ckpt / "vecnormalize.pkl"))
            export(model, ckpt / "policy", spec.algo, run.cfg["env_kwargs"], run.frame_stack, vn,
                   {**trained, "n_timesteps": int(model.num_timesteps)}, run.unit_actions)
            metrics = {"timesteps": int(model.num_timesteps), "seed": seed,
                       **score_policy(ckpt / "policy.zip", spec.objective),
                       "wall_s": round(time.perf_counter() - started, 1)}
            if not math.isfinite(metrics[METRIC]):
                raise FloatingPointError(f"benchmark RMSE is {metrics[METRIC]}")
            report(metrics, ckpt)
    return metrics


def _trainable(config: dict[str, Any], spec: SweepSpec) -> None:
    """Ray Tune's function trainable: one seed of one sampled configuration."""
    import ray
    from ray import tune

    seed = spec.seeds[int(config.get("__trial_index__", 0)) % len(spec.seeds)]
    node_id = ray.get_runtime_context().get_node_id()
    # The trial's folder under --out (which every node reaches): SB3 writes TensorBoard there
    # directly, beside Tune's own event file (Tune's artifact sync lost a finishing trial's).
    trial_dir = Path(tune.get_context().get_storage().trial_fs_path)
    ckpt = tune.get_checkpoint()

    def report(metrics: dict[str, Any], ckpt_dir: Path) -> None:
        tune.report({**metrics, "node_id": node_id, "error": ""},
                    checkpoint=tune.Checkpoint.from_directory(str(ckpt_dir)))

    try:
        if ckpt is not None:
            with ckpt.as_directory() as d:
                resume = Path(tempfile.mkdtemp(prefix="resume_"))
                shutil.copytree(d, resume, dirs_exist_ok=True)
            train_and_score(spec, config, seed, report, trial_dir, resume)
        else:
            train_and_score(spec, config, seed, report, trial_dir)
    except Exception as exc:  # the trial's own failure: a result row with the error, no retry
        tune.report({"timesteps": -1, "seed": seed, METRIC: float("nan"), "node_id": node_id,
                     "error": f"{type(exc).__name__}: {exc}"})


def _progress_callback(spec: SweepSpec):
    from ray import tune

    class Progress(tune.Callback):
        """One line per finished trial."""

        def __init__(self) -> None:
            self.done = 0

        def _line(self, trial, status: str) -> None:
            self.done += 1
            r = trial.last_result or {}
            params = {k: _short(v) for k, v in trial.config.items() if not k.startswith("__")}
            if r.get("error"):
                status, what = "error", r["error"]
            elif status == "error":
                err = (trial.get_error() or "").strip().splitlines()
                what = err[-1] if err else "trial failed"
            else:
                if 0 <= r.get("timesteps", 0) < spec.n_timesteps:
                    status = "stopped early (ASHA or Ctrl-C)"
                what = (f"rmse {r.get(METRIC, float('nan')):.2f} deg after "
                        f"{r.get('timesteps', 0):,} steps")
            node = str(r.get("node_id", ""))[:8]
            print(f"[{self.done}/{spec.num_samples * len(spec.seeds)}] trial {trial.trial_id} "
                  f"seed {r.get('seed', '?')} {params}: {status}: {what}"
                  + (f" (node {node}, {r.get('wall_s', 0):.0f} s)" if node else ""), flush=True)

        def on_trial_complete(self, iteration, trials, trial, **info):
            self._line(trial, "finished")

        def on_trial_error(self, iteration, trials, trial, **info):
            self._line(trial, "error")

    return Progress()


def _short(v: Any) -> Any:
    return float(f"{v:.3g}") if isinstance(v, float) else v


def run_sweep(spec: SweepSpec, out: Path, address: str | None = LOCAL,
              max_failures: int = 2) -> list[dict[str, Any]]:
    """Run the sweep (Ctrl-C: stop, keep the finished trials); returns one row per trial."""
    # Our own progress lines and table replace Tune's live table and per-checkpoint log lines.
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    connect(address, worker_logs=False)
    import optuna
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import Repeater
    from ray.tune.search.optuna import OptunaSearch

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    searcher = Repeater(OptunaSearch(sampler=optuna.samplers.TPESampler(seed=spec.search_seed)),
                        repeat=len(spec.seeds), set_index=True)
    scheduler = ASHAScheduler(time_attr="timesteps", max_t=spec.n_timesteps,
                              grace_period=spec.grace_period,
                              reduction_factor=spec.reduction_factor)
    out.mkdir(parents=True, exist_ok=True)
    tuner = tune.Tuner(
        tune.with_resources(tune.with_parameters(_trainable, spec=spec), {"cpu": 1}),
        param_space=tune_space(spec),
        tune_config=tune.TuneConfig(metric=METRIC, mode="min", search_alg=searcher,
                                    scheduler=scheduler,
                                    num_samples=spec.num_samples * len(spec.seeds),
                                    max_concurrent_trials=spec.max_concurrent,
                                    trial_dirname_creator=lambda t: f"trial_{t.trial_id}"),
        run_config=tune.RunConfig(
            name="trials", storage_path=str(out.resolve()), verbose=0,
            callbacks=[_progress_callback(spec)],
            failure_config=tune.FailureConfig(max_failures=max_failures),
            checkpoint_config=tune.CheckpointConfig(num_to_keep=1)))
    grid = tuner.fit()
    rows = []
    for res in grid:
        m = dict(res.metrics or {})
        params = {k: v for k, v in (res.config or {}).items() if not k.startswith("__")}
        error = m.get("error") or (f"{type(res.error).__name__}: {res.error}".splitlines()[0]
                                   if res.error else "")
        timesteps = int(m.get("timesteps", -1) or -1)
        status = ("error" if error else "finished" if timesteps >= spec.n_timesteps
                  else "stopped early" if timesteps > 0 else "not run")
        rows.append({"trial_id": m.get("trial_id", Path(res.path).name), "status": status,
                     "seed": m.get("seed", ""), **{f"param.{k}": v for k, v in params.items()},
                     "timesteps": timesteps, **{k: m.get(k, "") for k in RESULT_COLUMNS[4:]},
                     "error": error,
                     "checkpoint": res.checkpoint.path if res.checkpoint and not error else "",
                     "curve": _curve(res)})
    return sorted(rows, key=lambda r: (_num(r["rmse_deg"]), str(r["trial_id"])))


def _curve(res) -> list[tuple[int, float]]:
    df = res.metrics_dataframe
    if df is None or "timesteps" not in df or METRIC not in df:
        return []
    return [(int(t), float(v)) for t, v in zip(df["timesteps"], df[METRIC]) if t > 0]


def _num(v: Any) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return math.inf
    return x if math.isfinite(x) else math.inf


def write_results(rows: list[dict[str, Any]], out: Path) -> Path:
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols and k != "curve"]
    path = out / "results.csv"
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in cols})
    return path


def format_table(rows: list[dict[str, Any]]) -> str:
    pcols = sorted({k for r in rows for k in r if k.startswith("param.")})
    head = (f"{'trial':<14s} {'seed':>4s} " + " ".join(f"{c[6:]:>15s}" for c in pcols)
            + f" {'steps':>9s} {'RMSE deg':>8s} {'energy J':>8s}  status")
    lines = [head, "-" * len(head)]
    for r in rows:
        rm, en = _num(r.get("rmse_deg")), _num(r.get("energy_J"))
        lines.append(f"{str(r['trial_id']):<14s} {str(r['seed']):>4s} "
                     + " ".join(f"{str(_short(r.get(c, ''))):>15s}" for c in pcols)
                     + f" {r['timesteps']:>9,d} "
                     + (f"{rm:8.2f}" if math.isfinite(rm) else f"{'-':>8s}") + " "
                     + (f"{en:8.0f}" if math.isfinite(en) else f"{'-':>8s}")
                     + f"  {r['status']}" + (f": {r['error']}" if r["error"] else ""))
    return "\n".join(lines)


def write_plot(rows: list[dict[str, Any]], path: Path, spec: SweepSpec) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.5))
    pcols = sorted({k for r in rows for k in r if k.startswith("param.")})
    configs: list[tuple] = []
    for r in rows:
        key = tuple(_short(r.get(c)) for c in pcols)
        if key not in configs:
            configs.append(key)
    colors = plt.get_cmap("tab10").colors
    for r in rows:
        if not r["curve"]:
            continue
        k = configs.index(tuple(_short(r.get(c)) for c in pcols))
        t, v = zip(*r["curve"])
        ax0.plot(t, v, marker="o", color=colors[k % 10], ls="-" if str(r["seed"]) == str(spec.seeds[0])
                 else "--", label=f"config {k} seed {r['seed']}")
        ax1.plot([k], [v[-1]], "o", color=colors[k % 10])
    ax0.set_xlabel("training steps")
    ax0.set_ylabel("benchmark RMSE (deg)")
    ax0.set_title("RMSE during training (ASHA stops the worst early)")
    ax0.legend(fontsize=7, ncol=2)
    ax1.set_xticks(range(len(configs)))
    ax1.set_xticklabels(["\n".join(f"{c[6:]}={v}" for c, v in zip(pcols, key)) for key in configs],
                        fontsize=6)
    ax1.set_ylabel("final benchmark RMSE (deg), one point per seed")
    ax1.set_title(f"{spec.name}: {len(configs)} configurations x {len(spec.seeds)} seeds")
    for ax in (ax0, ax1):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def ship_best(rows: list[dict[str, Any]], out: Path, ship: Path | None) -> Path | None:
    """Copy the best trial's deployable policy to ``out/best_policy`` (and to ``ship``): the
    lowest RMSE among the trials that trained their whole budget (else among all)."""
    scored = [r for r in rows if r["checkpoint"] and math.isfinite(_num(r["rmse_deg"]))]
    best = next((r for r in scored if r["status"] == "finished"), scored[0] if scored else None)
    if best is None:
        return None
    src = Path(best["checkpoint"]) / "policy.zip"
    targets = [out / "best_policy"] + ([ship] if ship is not None else [])
    for t in targets:
        dst = Path(t).with_suffix(".zip")
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
        shutil.copy2(src.with_suffix(".json"), dst.with_suffix(".json"))
    return Path(targets[-1]).with_suffix(".zip")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m agents.sweep", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("spec", type=Path, help="sweep file, e.g. agents/sweeps/ppo.yml")
    p.add_argument("--address", default=None,
                   help="Ray cluster to join: 'auto', HOST:PORT or ray://HOST:10001 (default: an "
                        "embedded Ray on this machine); the project ships as the job's "
                        "runtime environment, and --out must be a folder every node can reach")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/sweeps/NAME)")
    p.add_argument("--ship", type=Path, default=None,
                   help="also export the best trial's deployable policy to this path (.zip + .json)")
    p.add_argument("--num-samples", type=int, default=None, help="override the file's num_samples")
    p.add_argument("--n-timesteps", type=float, default=None, help="override the file's n_timesteps")
    p.add_argument("--report-every", type=float, default=None, help="override the file's report_every")
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="override the file's seeds")
    p.add_argument("--max-failures", type=int, default=2,
                   help="restarts of a trial whose worker or node died (from its last checkpoint)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import_ray()
    over = {"num_samples": args.num_samples, "n_timesteps": args.n_timesteps,
            "report_every": args.report_every, "seeds": args.seeds}
    spec = load_spec(args.spec, over)
    out = args.out or Path("runs") / "sweeps" / spec.name
    n_trials = spec.num_samples * len(spec.seeds)
    print(f"sweep {spec.source}: {spec.num_samples} configurations x seeds {list(spec.seeds)} = "
          f"{n_trials} trials of {spec.n_timesteps:,} steps ({spec.algo}, report every "
          f"{spec.report_every:,}); objective: benchmark RMSE, {spec.objective.episodes} x "
          f"{spec.objective.episode_s:g} s, {spec.objective.energy_budget_J:g} J; "
          f"Ray: {args.address or 'embedded'}", flush=True)
    t0 = time.perf_counter()
    rows = run_sweep(spec, out, args.address or LOCAL, args.max_failures)
    wall = time.perf_counter() - t0
    print()
    print(format_table(rows))
    csv_path = write_results(rows, out)
    write_plot(rows, out / "sweep.png", spec)
    shipped = ship_best(rows, out, args.ship)
    done = sum(r["status"] != "not run" for r in rows)
    print(f"\n{done}/{n_trials} trials ran in {wall:.0f} s; wrote {csv_path}, {out / 'sweep.png'}"
          + (f"; best policy {shipped} (+ .json)" if shipped else "; no trial finished"))
    (out / "summary.json").write_text(json.dumps(
        {"spec": spec.source, "wall_s": round(wall, 1), "trials": n_trials, "ran": done,
         "shipped": str(shipped) if shipped else None}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    # Run the importable module's main: Ray workers then find its functions by name.
    from agents.sweep import main as _main

    sys.exit(_main())
