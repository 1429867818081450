"""Benchmark every controller on one fixed, seeded suite of target trajectories.

    python -m agents.benchmark                          # 5 x 60 s episodes, seeds 1000-1004
    python -m agents.benchmark --quick                  # 1 episode of 10 s (smoke test)
    python -m agents.benchmark --controllers pid,mpc --episodes 3 --json out.json
    python -m agents.benchmark --action-mode relay      # the same suite through the relays
    python -m agents.benchmark --ray [auto]             # episodes as Ray tasks (agents.distributed)

Suite: ``NeckTrack-v0`` with its defaults (calibrated plant, sensor noise and biases, the
default target distribution, the default energy budget; nothing randomized) reset with seeds
``seed, seed + 1, ...``. Every controller sees the same targets, noise and budget.

Controllers: the heuristics and the MPC of ``agents.controllers`` and every saved SB3 policy
``agents/policies/NAME.zip`` with a sibling ``NAME.json`` (``{"algo": "PPO" | "SAC" | ...,
"env_kwargs": {...}, ...}``), loaded with ``agents.policy.DeployedPolicy`` (the SB3 class's
``.load(path, device="cpu")``, ``predict(obs, deterministic=True)``, plus the observation
normalization / frame stacking / action scaling recorded in the JSON). A policy runs in the
suite env with its own action interface (``action_mode``, ``supply_current_A``, ``dt`` from its
``env_kwargs``); everything else (budget, episode length, targets, noise) is the suite's.

Metrics (per episode, from the env's ``info`` at every step):

| column            | meaning                                                                  |
|-------------------|--------------------------------------------------------------------------|
| `controller`      | controller name (policy: file stem)                                      |
| `kind`            | `heuristic`, `model-based` or `learned`                                  |
| `action_mode`     | `current` or `relay`                                                     |
| `episode`         | index in the suite (0, 1, ...), or `all` for the aggregate row           |
| `seed`            | env reset seed (empty on aggregate rows)                                 |
| `steps`           | env steps (aggregate: sum)                                               |
| `rmse_deg`        | sqrt(mean(tracking_error_deg^2)) over the steps (aggregate: pooled over all steps) |
| `mean_err_deg`    | mean tracking error (aggregate: pooled)                                  |
| `max_err_deg`     | largest tracking error (aggregate: max over episodes)                    |
| `within_2deg_frac`| fraction of steps with tracking error < 2 deg (aggregate: pooled)        |
| `energy_J`        | `info["energy_J"]` after the last step (aggregate: mean per episode)     |
| `budget_exhausted`| `info["budget_exhausted"]` after the last step, 0/1 (aggregate: episodes exhausted) |
| `max_temp_C`      | hottest true spring temperature seen (aggregate: max)                    |
| `wall_s`          | wall time of the episode incl. the controller (aggregate: mean)          |

Pooled aggregates are recomputable from the episode rows: ``rmse_all^2 = sum(steps_i rmse_i^2) /
sum(steps_i)``, likewise for the mean and the within-2-deg fraction (``tests/test_agents.py``
does exactly that).

Outputs (``--out-dir``, default ``runs/benchmark/``): ``benchmark.csv`` (one row per controller
per episode, then one aggregate row per controller), ``benchmark.json`` (``{"suite": {...},
"controllers": [{"name", "kind", "action_mode", "rmse_deg", "energy_J", "budget_exhausted",
..., "episodes": [...]}], "notes": [...]}``; ``budget_exhausted`` is true if any episode
exhausted the budget) and ``benchmark.png`` (theta and phi against the target over time for
every controller on the first suite episode). ``--csv``, ``--json``, ``--plot`` override the
paths. The table is printed to the terminal.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable

import numpy as np

from neck_env.envs import NeckTrackEnv
from neck_env.task import DEFAULT_BUDGET_J

from .controllers import CONTROLLERS, make_controller
from .distributed import LOCAL, add_ray_argument, fan_out
from .policy import DeployedPolicy

DEFAULT_CONTROLLERS = ("zero", "full_on", "open_loop", "open_loop_lead", "bang_bang", "pid", "mpc")
POLICY_DIR = Path(__file__).resolve().parent / "policies"
# Keys of a policy's env_kwargs that define its interface (kept); the rest is the suite's.
POLICY_INTERFACE_KEYS = ("action_mode", "supply_current_A", "dt")
CSV_COLUMNS = ("controller", "kind", "action_mode", "episode", "seed", "steps", "rmse_deg",
               "mean_err_deg", "max_err_deg", "within_2deg_frac", "energy_J",
               "budget_exhausted", "max_temp_C", "wall_s")
WITHIN_DEG = 2.0


@dataclass
class Agent:
    """Anything the benchmark can run: reset per episode, act on one observation."""

    name: str
    kind: str
    env_kwargs: dict[str, Any]
    reset: Callable[[int], None]
    act: Callable[[np.ndarray], np.ndarray]
    extra: dict[str, Any] = field(default_factory=dict)
    # Builds the same agent again in another process (a Ray worker, maybe on another machine):
    # a picklable module-level call carrying everything it needs (a policy's file contents).
    rebuild: Callable[[], "Agent"] | None = None


@dataclass
class Episode:
    seed: int
    t_s: np.ndarray
    err: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    target_theta: np.ndarray
    target_phi: np.ndarray
    energy_J: float
    budget_exhausted: bool
    max_temp_C: float
    wall_s: float

    def row(self) -> dict[str, Any]:
        e = self.err
        return {"steps": int(e.size), "rmse_deg": float(np.sqrt(np.mean(e ** 2))),
                "mean_err_deg": float(np.mean(e)), "max_err_deg": float(np.max(e)),
                "within_2deg_frac": float(np.mean(e < WITHIN_DEG)),
                "energy_J": float(self.energy_J), "budget_exhausted": int(self.budget_exhausted),
                "max_temp_C": float(self.max_temp_C), "wall_s": float(self.wall_s)}


def suite_env_kwargs(episode_s: float, energy_budget_J: float, action_mode: str) -> dict[str, Any]:
    return {"action_mode": action_mode, "episode_s": episode_s, "energy_budget_J": energy_budget_J}


def controller_agent(name: str, env_kwargs: dict[str, Any]) -> Agent:
    ctrl = make_controller(name, env_kwargs)
    label = name if env_kwargs["action_mode"] == "current" else f"{name}@relay"
    return Agent(label, ctrl.kind, env_kwargs, lambda seed: ctrl.reset(seed), ctrl.act,
                 {"controller": ctrl}, partial(controller_agent, name, dict(env_kwargs)))


def find_policies(policy_dir: Path) -> tuple[list[Path], list[str]]:
    """Policy zips with a sibling JSON carrying "algo" and "env_kwargs"; notes on the rest."""
    found, notes = [], []
    if not policy_dir.is_dir():
        return found, [f"no policy directory {policy_dir}"]
    for z in sorted(policy_dir.glob("*.zip")):
        meta = z.with_suffix(".json")
        if not meta.exists():
            notes.append(f"skipped {z.name}: no sibling {meta.name}")
            continue
        try:
            m = json.loads(meta.read_text())
        except json.JSONDecodeError as exc:
            notes.append(f"skipped {z.name}: {meta.name} is not valid JSON ({exc})")
            continue
        if not isinstance(m, dict) or "algo" not in m or "env_kwargs" not in m:
            notes.append(f"skipped {z.name}: {meta.name} lacks 'algo' or 'env_kwargs'")
            continue
        found.append(z)
    return found, notes


def policy_agent(zip_path: Path, suite_kwargs: dict[str, Any]) -> Agent:
    agent = _load_policy_agent(zip_path, suite_kwargs)
    agent.rebuild = partial(_policy_agent_from_contents, zip_path.stem, zip_path.read_bytes(),
                            zip_path.with_suffix(".json").read_text(), dict(suite_kwargs))
    return agent


def _policy_agent_from_contents(stem: str, zip_bytes: bytes, meta_text: str,
                                suite_kwargs: dict[str, Any]) -> Agent:
    with tempfile.TemporaryDirectory(prefix="policy_") as tmp:
        zip_path = Path(tmp) / f"{stem}.zip"
        zip_path.write_bytes(zip_bytes)
        zip_path.with_suffix(".json").write_text(meta_text)
        return _load_policy_agent(zip_path, suite_kwargs)


def _load_policy_agent(zip_path: Path, suite_kwargs: dict[str, Any]) -> Agent:
    meta = json.loads(zip_path.with_suffix(".json").read_text())
    env_kwargs = dict(suite_kwargs)
    for k in POLICY_INTERFACE_KEYS:
        if k in meta["env_kwargs"]:
            env_kwargs[k] = meta["env_kwargs"][k]
    pol = DeployedPolicy.load(zip_path)
    # actions outside the Box are the env's to clip (neck_env.task.Task.currents_A)
    return Agent(zip_path.stem, "learned", env_kwargs, lambda seed: pol.reset(), pol.act,
                 {"algo": meta["algo"], "trained_env_kwargs": meta["env_kwargs"]})


def run_episode(agent: Agent, env: NeckTrackEnv, seed: int) -> Episode:
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    n = env.task.episode_steps
    err, th, ph, tth, tph = (np.empty(n) for _ in range(5))
    max_T = float(np.max(info["temperatures_C"]))
    t0 = time.perf_counter()
    for k in range(n):
        obs, _, _, _, info = env.step(agent.act(obs))
        err[k] = info["tracking_error_deg"]
        th[k], ph[k] = info["theta_deg"], info["phi_deg"]
        tth[k], tph[k] = info["target_theta_deg"], info["target_phi_deg"]
        max_T = max(max_T, float(np.max(info["temperatures_C"])))
    wall = time.perf_counter() - t0
    return Episode(seed, env.dt * np.arange(1, n + 1), err, th, ph, tth, tph,
                   float(info["energy_J"]), bool(info["budget_exhausted"]), max_T, wall)


def aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    steps = np.array([r["steps"] for r in rows], dtype=float)
    w = steps / steps.sum()
    return {"steps": int(steps.sum()),
            "rmse_deg": float(np.sqrt(np.sum(w * np.array([r["rmse_deg"] for r in rows]) ** 2))),
            "mean_err_deg": float(np.sum(w * np.array([r["mean_err_deg"] for r in rows]))),
            "max_err_deg": float(max(r["max_err_deg"] for r in rows)),
            "within_2deg_frac": float(np.sum(w * np.array([r["within_2deg_frac"] for r in rows]))),
            "energy_J": float(np.mean([r["energy_J"] for r in rows])),
            "budget_exhausted": int(sum(r["budget_exhausted"] for r in rows)),
            "max_temp_C": float(max(r["max_temp_C"] for r in rows)),
            "wall_s": float(np.mean([r["wall_s"] for r in rows]))}


_WORKER_AGENTS: dict[str, Agent] = {}  # per worker process: agents built for earlier episodes


def episode_task(item: tuple[str, Callable[[], Agent], int]) -> Episode:
    """One suite episode in another process: rebuild the agent (once per process), run."""
    key, rebuild, seed = item
    if key not in _WORKER_AGENTS:
        _WORKER_AGENTS[key] = rebuild()
    agent = _WORKER_AGENTS[key]
    return run_episode(agent, NeckTrackEnv(**agent.env_kwargs), seed)


def run_episodes(agents: list[Agent], seeds: list[int],
                 ray_address: str | None = None) -> list[list[Episode]]:
    """Every agent on every seed: here, or one Ray task per episode (``ray_address``)."""
    if ray_address is None:
        out = []
        for ag in agents:
            env = NeckTrackEnv(**ag.env_kwargs)
            out.append([run_episode(ag, env, seed) for seed in seeds])
        return out
    items = [(f"{ag.name} {json.dumps(ag.env_kwargs, sort_keys=True)}", ag.rebuild, seed)
             for ag in agents for seed in seeds]
    names = [f"{ag.name} seed {seed}" for ag in agents for seed in seeds]
    missing = [ag.name for ag in agents if ag.rebuild is None]
    if missing:
        raise ValueError(f"agents {missing} cannot be rebuilt in a Ray worker (no rebuild)")

    def line(o, k, n):
        where = "" if o.node_id == LOCAL else f" on node {o.node_id[:8]}"
        what = (f"rmse {o.value.row()['rmse_deg']:.2f} deg" if o.error is None
                else "FAILED " + o.error.splitlines()[0])
        print(f"  [{k}/{n}] {names[o.index]}: {what}{where} ({o.wall_s:.1f} s)", flush=True)

    outcomes = fan_out(episode_task, items, ray_address, progress=line)
    failed = [f"{names[o.index]}: {o.error}" for o in outcomes if o.error is not None]
    if failed:
        raise RuntimeError("episodes failed in Ray workers:\n" + "\n".join(failed))
    it = iter(o.value for o in outcomes)
    return [[next(it) for _ in seeds] for _ in agents]


def run_suite(agents: list[Agent], seeds: list[int], log=print,
              ray_address: str | None = None) -> list[dict[str, Any]]:
    results = []
    for ag, episodes in zip(agents, run_episodes(agents, seeds, ray_address)):
        rows = [dict(ep.row(), seed=ep.seed, episode=i) for i, ep in enumerate(episodes)]
        agg = aggregate(rows)
        log(f"  {ag.name:<22s} rmse {agg['rmse_deg']:6.2f} deg  energy {agg['energy_J']:7.1f} J  "
            f"({agg['wall_s']:.2f} s/episode)")
        results.append({"agent": ag, "episodes": episodes, "rows": rows, "aggregate": agg})
    return results


def format_table(results: list[dict[str, Any]], budget_J: float) -> str:
    head = (f"{'controller':<22s} {'kind':<11s} {'RMSE':>6s} {'mean':>6s} {'worst':>6s} "
            f"{'<2deg':>6s} {'energy':>8s} {'exhausted':>9s} {'T max':>6s} {'s/ep':>6s}")
    units = (f"{'':<22s} {'':<11s} {'deg':>6s} {'deg':>6s} {'deg':>6s} {'frac':>6s} "
             f"{'J/ep':>8s} {'episodes':>9s} {'C':>6s} {'':>6s}")
    lines = [head, units, "-" * len(head)]
    for r in results:
        a, ag = r["aggregate"], r["agent"]
        n = len(r["rows"])
        lines.append(f"{ag.name:<22s} {ag.kind:<11s} {a['rmse_deg']:6.2f} {a['mean_err_deg']:6.2f} "
                     f"{a['max_err_deg']:6.2f} {a['within_2deg_frac']:6.3f} {a['energy_J']:8.1f} "
                     f"{a['budget_exhausted']:>4d}/{n:<4d} {a['max_temp_C']:6.1f} {a['wall_s']:6.2f}")
    lines.append(f"(budget {budget_J:g} J per episode; RMSE/mean/<2deg pooled over all steps, "
                 "worst = largest error, energy = mean per episode)")
    return "\n".join(lines)


def write_csv(path: Path, results: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in results:
            ag = r["agent"]
            base = {"controller": ag.name, "kind": ag.kind,
                    "action_mode": ag.env_kwargs.get("action_mode", "current")}
            for row in r["rows"]:
                w.writerow({**base, **_fmt(row)})
            w.writerow({**base, **_fmt(r["aggregate"]), "episode": "all", "seed": ""})


def _fmt(row: dict[str, Any]) -> dict[str, Any]:
    return {k: (repr(float(v)) if isinstance(v, float) else v) for k, v in row.items()}


def write_json(path: Path, results: list[dict[str, Any]], suite: dict[str, Any],
               notes: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ctrls = []
    for r in results:
        ag, a = r["agent"], r["aggregate"]
        entry = {"name": ag.name, "kind": ag.kind,
                 "action_mode": ag.env_kwargs.get("action_mode", "current"),
                 "rmse_deg": a["rmse_deg"], "energy_J": a["energy_J"],
                 "budget_exhausted": bool(a["budget_exhausted"] > 0),
                 "budget_exhausted_episodes": a["budget_exhausted"],
                 "mean_err_deg": a["mean_err_deg"], "max_err_deg": a["max_err_deg"],
                 "within_2deg_frac": a["within_2deg_frac"], "max_temp_C": a["max_temp_C"],
                 "wall_s_per_episode": a["wall_s"], "steps": a["steps"],
                 "episodes": [{**row, "budget_exhausted": bool(row["budget_exhausted"])}
                              for row in r["rows"]]}
        ctrl = ag.extra.get("controller")
        if ctrl is not None and hasattr(ctrl, "plan_seconds"):
            entry["note"] = "wall_s includes the MPC's planning"
        if "algo" in ag.extra:
            entry["algo"] = ag.extra["algo"]
            entry["trained_env_kwargs"] = ag.extra["trained_env_kwargs"]
        ctrls.append(entry)
    path.write_text(json.dumps({"suite": suite, "controllers": ctrls, "notes": notes},
                               indent=2, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def write_plot(path: Path, results: list[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(3, 1, figsize=(11, 9), sharex=True)
    first = results[0]["episodes"][0]
    t = first.t_s
    axes[0].plot(t, first.target_theta, "k--", lw=2, label="target")
    tphi = np.where(first.target_theta > 0.05, first.target_phi, np.nan)
    axes[1].plot(t, tphi, "k--", lw=2, label="target")
    colors = plt.get_cmap("tab10").colors
    bases: list[str] = []
    for r in results:
        ep = r["episodes"][0]
        name = r["agent"].name
        base = name.split("@")[0]
        if base not in bases:
            bases.append(base)
        style = dict(lw=1.2, label=name, color=colors[bases.index(base) % len(colors)],
                     ls=":" if name.endswith("@relay") else "-")
        axes[0].plot(ep.t_s, ep.theta, **style)
        # phi is undefined upright: drawn only while the head tilts more than 1 deg, and
        # broken where it wraps through 0/360
        phi = np.where(ep.theta > 1.0, ep.phi, np.nan)
        phi[1:][np.abs(np.diff(phi)) > 180.0] = np.nan
        axes[1].plot(ep.t_s, phi, **style)
        axes[2].plot(ep.t_s, ep.err, **style)
    axes[0].set_ylabel("theta (deg)")
    axes[1].set_ylabel("phi (deg)")
    axes[1].set_ylim(0, 360)
    axes[2].set_ylabel("tracking error (deg)")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title(f"First suite episode (seed {first.seed}): head pose against the target")
    axes[0].legend(loc="upper left", fontsize=8, ncol=4)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m agents.benchmark",
        description="Run the heuristic controllers, the MPC and any saved SB3 policy on a fixed, "
                    "seeded suite of NeckTrack-v0 target trajectories under one energy budget; "
                    "print a table and write CSV, JSON and a plot.",
        epilog="CSV columns: " + ", ".join(CSV_COLUMNS) + ". One row per controller per "
               "episode, then one aggregate row (episode = 'all'). See the module docstring "
               "(python -c 'import agents.benchmark as b; help(b)') for their definitions.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--controllers", default=",".join(DEFAULT_CONTROLLERS + ("policies",)),
                   help="comma-separated subset of " + ", ".join(sorted(CONTROLLERS))
                        + ", plus 'policies' (every saved policy in --policy-dir) or a policy's "
                          "file stem")
    p.add_argument("--episodes", type=int, default=5, help="number of suite episodes")
    p.add_argument("--seed", type=int, default=1000,
                   help="env reset seed of the first episode; episode i uses seed + i")
    p.add_argument("--episode-s", type=float, default=60.0, help="episode length in seconds")
    p.add_argument("--energy-budget", type=float, default=DEFAULT_BUDGET_J,
                   help="energy budget per episode in J (the env default; 'inf' for none)")
    p.add_argument("--action-mode", choices=("current", "relay", "both"), default="current",
                   help="action interface for the hand-written controllers and the MPC "
                        "('both' runs each twice; relay runs are named NAME@relay). Policies "
                        "always use the mode they were trained in")
    p.add_argument("--policy-dir", type=Path, default=POLICY_DIR,
                   help="where to look for NAME.zip + NAME.json policies")
    p.add_argument("--quick", action="store_true",
                   help="smoke test: 1 episode of 10 s (overrides --episodes and --episode-s)")
    p.add_argument("--out-dir", type=Path, default=Path("runs/benchmark"),
                   help="directory for the default CSV, JSON and plot paths")
    p.add_argument("--csv", type=Path, default=None, help="CSV path (default OUT_DIR/benchmark.csv)")
    p.add_argument("--json", type=Path, default=None,
                   help="JSON path (default OUT_DIR/benchmark.json)")
    p.add_argument("--plot", type=Path, default=None,
                   help="PNG path of the first episode's theta/phi plot (default "
                        "OUT_DIR/benchmark.png)")
    p.add_argument("--no-plot", action="store_true", help="skip the plot")
    add_ray_argument(p, "episodes")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    episodes, episode_s = (1, 10.0) if args.quick else (args.episodes, args.episode_s)
    if episodes < 1:
        raise SystemExit("--episodes must be >= 1")
    seeds = [args.seed + i for i in range(episodes)]
    modes = ("current", "relay") if args.action_mode == "both" else (args.action_mode,)
    wanted = [c.strip() for c in args.controllers.split(",") if c.strip()]
    notes: list[str] = []
    agents: list[Agent] = []
    policies, pol_notes = find_policies(args.policy_dir)
    by_stem = {p.stem: p for p in policies}
    for mode in modes:
        kw = suite_env_kwargs(episode_s, args.energy_budget, mode)
        for name in wanted:
            if name in CONTROLLERS:
                agents.append(controller_agent(name, kw))
    base_kw = suite_env_kwargs(episode_s, args.energy_budget, "current")
    chosen = policies if "policies" in wanted else [by_stem[w] for w in wanted if w in by_stem]
    unknown = [w for w in wanted if w not in CONTROLLERS and w not in by_stem and w != "policies"]
    if unknown:
        raise SystemExit(f"unknown controller(s) {unknown}; known: {sorted(CONTROLLERS)}, "
                         f"'policies', or a policy stem in {args.policy_dir} "
                         f"({sorted(by_stem) or 'none found'})")
    if "policies" in wanted or chosen:
        notes += pol_notes
        if not chosen:
            notes.append(f"no saved SB3 policy (NAME.zip + NAME.json) in {args.policy_dir}: "
                         "learned controllers skipped")
    for z in chosen:
        try:
            agents.append(policy_agent(z, base_kw))
        except Exception as exc:  # a broken policy must not sink the benchmark
            notes.append(f"skipped policy {z.name}: {type(exc).__name__}: {exc}")
    for n in notes:
        print(f"note: {n}")
    if not agents:
        raise SystemExit("nothing to run")
    print(f"suite: {episodes} episode(s) x {episode_s:g} s, seeds {seeds[0]}..{seeds[-1]}, "
          f"energy budget {args.energy_budget:g} J")
    t0 = time.perf_counter()
    results = run_suite(agents, seeds, ray_address=args.ray)
    print()
    print(format_table(results, args.energy_budget))
    suite = {"env_id": "NeckTrack-v0", "seeds": seeds, "episode_s": episode_s,
             "energy_budget_J": args.energy_budget, "action_modes": list(modes),
             "env_kwargs": base_kw, "wall_s": time.perf_counter() - t0}
    csv_path = args.csv or args.out_dir / "benchmark.csv"
    json_path = args.json or args.out_dir / "benchmark.json"
    write_csv(csv_path, results)
    write_json(json_path, results, suite, notes)
    print(f"\nwrote {csv_path} and {json_path}", end="")
    if not args.no_plot:
        plot_path = args.plot or args.out_dir / "benchmark.png"
        write_plot(plot_path, results)
        print(f" and {plot_path}", end="")
    print()
    return 0


if __name__ == "__main__":
    # Run the importable module's main: Ray workers then find its functions by name.
    from agents.benchmark import main as _main

    sys.exit(_main())
