"""Benchmark every controller on one fixed, seeded suite of target trajectories.

    python -m agents.benchmark                          # NeckTrack-v1, 3 suites x 30 x 60 s
    python -m agents.benchmark --quick                  # 1 episode of 10 s per suite (smoke test)
    python -m agents.benchmark --controllers pid,mpc --episodes 3 --json out.json
    python -m agents.benchmark --env-id NeckTrack-v0 --suites nominal --episodes 5   # the old table
    python -m agents.benchmark --action-mode relay      # the suites through the relays only
    python -m agents.benchmark --ray [auto]             # episodes as Ray tasks (agents.distributed)

Suites (``--suites``, all three by default), each reset with seeds ``seed, seed + 1, ...``
(``--episodes``, 30 by default: five episodes ranked controllers wrongly, see issue 14), on the
env id's defaults (``--env-id``, ``NeckTrack-v1``: 900 J, firmware actuation; ``--energy-budget``
and ``--actuation`` override them):

| suite | per episode |
|---|---|
| `nominal` | the calibrated plant, sensor noise and biases, the default targets |
| `randomized` | ``randomize=True``: plant parameters drawn per episode (``Randomization``) |
| `effects` | one unmodelled effect of the catalogue (``neck_env.effects``), episode i the i-th name in turn, its parameters drawn within their ranges |

Every controller sees the same targets, noise, plant and budget in an episode, so episodes are
paired: for every controller the benchmark reports the mean over episodes of its RMSE minus the
best heuristic's (the heuristic with the lowest pooled RMSE in that suite and action mode) with
a 95 % bootstrap interval (``scipy.stats.bootstrap``, BCa, 9999 resamples, seeded): an
interval below zero means the controller beats the best heuristic on this suite's population
of episodes. The MPC (5 s per episode) runs on ``--mpc-suites`` (``nominal`` by default) to
keep the default run under 10 minutes. ``--action-mode both`` (default) runs the hand-written
controllers in current and relay mode (relay runs are named ``NAME@relay``; the MPC runs in
current mode only).

Controllers: the heuristics and the MPC of ``agents.controllers`` and every saved policy
``agents/policies/NAME.zip`` with a sibling ``NAME.json`` (``{"algo": "PPO" | "SAC" | ... |
"ARS", "env_kwargs": {...}, ...}``), loaded with ``agents.policy.DeployedPolicy`` (for SB3 the
class's ``.load(path, device="cpu")``, ``predict(obs, deterministic=True)``, plus the observation
normalization / frame stacking / action scaling recorded in the JSON; for ARS the muscle-shared
law or the residual it names). A policy runs in the
suite env with its own action interface (``action_mode``, ``supply_current_A``, ``dt`` from its
``env_kwargs``); everything else (budget, episode length, targets, noise) is the suite's.

Metrics (per episode, from the env's ``info`` at every step):

| column            | meaning                                                                  |
|-------------------|--------------------------------------------------------------------------|
| `controller`      | controller name (policy: file stem)                                      |
| `suite`           | `nominal`, `randomized` or `effects`                                     |
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
..., "paired_vs_best_heuristic": {"reference", "mean_diff_deg", "ci95_deg"}, "episodes": [...]}],
"suites": {SUITE: {"controllers": [...], "best_heuristic": {...}}}, "notes": [...]}``:
``controllers`` is the first suite's (nominal by default), ``suites`` has every suite;
``budget_exhausted`` is true if any episode exhausted the budget) and ``benchmark.png`` (theta and phi against the target over time for
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

import neck_env
from neck_env import effects as fx
from neck_env.envs import NeckTrackEnv

from .controllers import CONTROLLERS, make_controller
from .distributed import LOCAL, add_ray_argument, fan_out
from .policy import DeployedPolicy

DEFAULT_CONTROLLERS = ("zero", "full_on", "open_loop", "open_loop_lead", "bang_bang", "pid", "mpc")
POLICY_DIR = Path(__file__).resolve().parent / "policies"
# Keys of a policy's env_kwargs that define its interface (kept); the rest is the suite's.
POLICY_INTERFACE_KEYS = ("action_mode", "supply_current_A", "dt")
CSV_COLUMNS = ("controller", "suite", "kind", "action_mode", "episode", "seed", "steps", "rmse_deg",
               "mean_err_deg", "max_err_deg", "within_2deg_frac", "energy_J",
               "budget_exhausted", "max_temp_C", "wall_s")
WITHIN_DEG = 2.0
SUITES = ("nominal", "randomized", "effects")
EFFECT_NAMES = tuple(fx.EFFECTS)
ENV_DEFAULTS = {"NeckTrack-v0": {"energy_budget_J": 1500.0, "actuation": "ideal"},
                "NeckTrack-v1": dict(neck_env.V1_KWARGS)}
DEFAULT_EPISODES = 30
BOOTSTRAP_RESAMPLES = 9999


def suite_overrides(suite: str, episode: int) -> dict[str, Any]:
    """The simulation keywords of one suite episode (on top of the task's)."""
    if suite == "nominal":
        return {}
    if suite == "randomized":
        return {"randomize": True}
    if suite == "effects":
        return {"effects": [EFFECT_NAMES[episode % len(EFFECT_NAMES)]]}
    raise ValueError(f"unknown suite {suite!r}; known: {SUITES}")


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


def suite_env_kwargs(episode_s: float, energy_budget_J: float, action_mode: str,
                     actuation: str | None = None) -> dict[str, Any]:
    """The task keywords of a suite (``actuation`` None: the task's default, "ideal")."""
    kw = {"action_mode": action_mode, "episode_s": episode_s, "energy_budget_J": energy_budget_J}
    if actuation is not None:
        kw["actuation"] = actuation
    return kw


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
    # a residual policy's PID models the suite's task (budget, episode length, actuation)
    pol = DeployedPolicy.load(zip_path, env_kwargs=env_kwargs)
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


def episode_task(item: tuple[str, Callable[[], Agent], int, dict[str, Any]]) -> Episode:
    """One suite episode in another process: rebuild the agent (once per process), run."""
    key, rebuild, seed, overrides = item
    if key not in _WORKER_AGENTS:
        _WORKER_AGENTS[key] = rebuild()
    agent = _WORKER_AGENTS[key]
    return run_episode(agent, NeckTrackEnv(**agent.env_kwargs, **overrides), seed)


def run_episodes(agents: list[Agent], seeds: list[int], ray_address: str | None = None,
                 suite: str = "nominal") -> list[list[Episode]]:
    """Every agent on every seed of ``suite``: here, or one Ray task per episode
    (``ray_address``)."""
    over = [suite_overrides(suite, i) for i in range(len(seeds))]
    if ray_address is None:
        out = []
        for ag in agents:
            envs: dict[str, NeckTrackEnv] = {}
            eps = []
            for seed, o in zip(seeds, over):
                key = json.dumps(o, sort_keys=True)
                if key not in envs:
                    envs[key] = NeckTrackEnv(**ag.env_kwargs, **o)
                eps.append(run_episode(ag, envs[key], seed))
            out.append(eps)
        return out
    items = [(f"{ag.name} {json.dumps(ag.env_kwargs, sort_keys=True)}", ag.rebuild, seed, o)
             for ag in agents for seed, o in zip(seeds, over)]
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
              ray_address: str | None = None, suite: str = "nominal") -> list[dict[str, Any]]:
    results = []
    for ag, episodes in zip(agents, run_episodes(agents, seeds, ray_address, suite)):
        rows = [dict(ep.row(), seed=ep.seed, episode=i) for i, ep in enumerate(episodes)]
        agg = aggregate(rows)
        log(f"  {suite:<10s} {ag.name:<22s} rmse {agg['rmse_deg']:6.2f} deg  energy "
            f"{agg['energy_J']:7.1f} J  ({agg['wall_s']:.2f} s/episode)")
        results.append({"agent": ag, "episodes": episodes, "rows": rows, "aggregate": agg,
                        "suite": suite})
    return results


def paired_vs_best_heuristic(results: list[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """For one suite's results: per action mode, the heuristic with the lowest pooled RMSE, and
    for every controller of that mode (``result["paired"]``) the mean over episodes of its
    RMSE minus the reference's, with a 95 % BCa bootstrap interval (paired: the same episodes).
    Returns {action_mode: reference name}."""
    from scipy.stats import bootstrap

    refs: dict[str, dict[str, Any]] = {}
    for r in results:
        mode = r["agent"].env_kwargs.get("action_mode", "current")
        if r["agent"].kind == "heuristic" and (
                mode not in refs or r["aggregate"]["rmse_deg"] < refs[mode]["aggregate"]["rmse_deg"]):
            refs[mode] = r
    for r in results:
        mode = r["agent"].env_kwargs.get("action_mode", "current")
        ref = refs.get(mode)
        if ref is None:
            r["paired"] = None
            continue
        d = (np.array([row["rmse_deg"] for row in r["rows"]])
             - np.array([row["rmse_deg"] for row in ref["rows"]]))
        ci: list[float] | None = None
        if d.size >= 2 and np.ptp(d) > 0:
            res = bootstrap((d,), np.mean, confidence_level=0.95, n_resamples=BOOTSTRAP_RESAMPLES,
                            method="BCa", rng=np.random.default_rng(seed))
            ci = [float(res.confidence_interval.low), float(res.confidence_interval.high)]
        elif d.size >= 2:  # the reference itself (or a twin): no spread, the difference is d
            ci = [float(d[0]), float(d[0])]
        r["paired"] = {"reference": ref["agent"].name, "mean_diff_deg": float(np.mean(d)),
                       "ci95_deg": ci, "episodes": int(d.size)}
    return {mode: ref["agent"].name for mode, ref in refs.items()}


def format_paired(p: dict[str, Any] | None) -> str:
    """``-0.42 [-0.61, -0.25]``: mean paired RMSE difference to the best heuristic, 95 % CI."""
    if p is None:
        return "-"
    if p["ci95_deg"] is None:
        return f"{p['mean_diff_deg']:+.2f} [n/a]"
    lo, hi = p["ci95_deg"]
    return f"{p['mean_diff_deg']:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def format_table(results: list[dict[str, Any]], budget_J: float) -> str:
    head = (f"{'controller':<22s} {'kind':<11s} {'RMSE':>6s} {'mean':>6s} {'worst':>6s} "
            f"{'<2deg':>6s} {'energy':>8s} {'exhausted':>9s} {'T max':>6s} {'s/ep':>6s}  "
            f"{'vs best heuristic':<22s}")
    units = (f"{'':<22s} {'':<11s} {'deg':>6s} {'deg':>6s} {'deg':>6s} {'frac':>6s} "
             f"{'J/ep':>8s} {'episodes':>9s} {'C':>6s} {'':>6s}  {'deg, 95 % CI':<22s}")
    lines = [head, units, "-" * len(head)]
    for r in results:
        a, ag = r["aggregate"], r["agent"]
        n = len(r["rows"])
        lines.append(f"{ag.name:<22s} {ag.kind:<11s} {a['rmse_deg']:6.2f} {a['mean_err_deg']:6.2f} "
                     f"{a['max_err_deg']:6.2f} {a['within_2deg_frac']:6.3f} {a['energy_J']:8.1f} "
                     f"{a['budget_exhausted']:>4d}/{n:<4d} {a['max_temp_C']:6.1f} {a['wall_s']:6.2f}  "
                     f"{format_paired(r.get('paired'))}")
    refs = sorted({r["paired"]["reference"] for r in results if r.get("paired")})
    lines.append(f"(budget {budget_J:g} J per episode; RMSE/mean/<2deg pooled over all steps, "
                 "worst = largest error, energy = mean per episode; vs best heuristic = mean over "
                 f"episodes of RMSE minus that of {' / '.join(refs) or 'the best heuristic'}, "
                 "paired, 95 % bootstrap interval)")
    return "\n".join(lines)


def write_csv(path: Path, results: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in results:
            ag = r["agent"]
            base = {"controller": ag.name, "suite": r.get("suite", "nominal"), "kind": ag.kind,
                    "action_mode": ag.env_kwargs.get("action_mode", "current")}
            for row in r["rows"]:
                w.writerow({**base, **_fmt(row)})
            w.writerow({**base, **_fmt(r["aggregate"]), "episode": "all", "seed": ""})


def _fmt(row: dict[str, Any]) -> dict[str, Any]:
    return {k: (repr(float(v)) if isinstance(v, float) else v) for k, v in row.items()}


def write_json(path: Path, results: list[dict[str, Any]], suite: dict[str, Any],
               notes: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    by_suite: dict[str, dict[str, Any]] = {}
    for r in results:
        name = r.get("suite", "nominal")
        by_suite.setdefault(name, {"controllers": [], "best_heuristic": {}})
        by_suite[name]["controllers"].append(_json_entry(r))
        if r.get("paired"):
            mode = r["agent"].env_kwargs.get("action_mode", "current")
            by_suite[name]["best_heuristic"][mode] = r["paired"]["reference"]
    first = next(iter(by_suite.values()), {"controllers": []})
    path.write_text(json.dumps({"suite": suite, "controllers": first["controllers"],
                                "suites": by_suite, "notes": notes},
                               indent=2, default=_json_default) + "\n")


def _json_entry(r: dict[str, Any]) -> dict[str, Any]:
    ag, a = r["agent"], r["aggregate"]
    entry = {"name": ag.name, "kind": ag.kind,
             "action_mode": ag.env_kwargs.get("action_mode", "current"),
             "rmse_deg": a["rmse_deg"], "energy_J": a["energy_J"],
             "budget_exhausted": bool(a["budget_exhausted"] > 0),
             "budget_exhausted_episodes": a["budget_exhausted"],
             "mean_err_deg": a["mean_err_deg"], "max_err_deg": a["max_err_deg"],
             "within_2deg_frac": a["within_2deg_frac"], "max_temp_C": a["max_temp_C"],
             "wall_s_per_episode": a["wall_s"], "steps": a["steps"],
             "suite": r.get("suite", "nominal"),
             "paired_vs_best_heuristic": r.get("paired"),
             "episodes": [{**row, "budget_exhausted": bool(row["budget_exhausted"])}
                          for row in r["rows"]]}
    ctrl = ag.extra.get("controller")
    if ctrl is not None and hasattr(ctrl, "plan_seconds"):
        entry["note"] = "wall_s includes the MPC's planning"
    if "algo" in ag.extra:
        entry["algo"] = ag.extra["algo"]
        entry["trained_env_kwargs"] = ag.extra["trained_env_kwargs"]
    return entry


def markdown_tables(data: dict[str, Any]) -> str:
    """The README's tables from a benchmark JSON (``--markdown``): one per suite, the figures
    the terminal table prints, rounded the same way."""
    out = []
    for suite, block in data["suites"].items():
        out.append(f"**{suite}** ({len(data['suite']['seeds'])} episodes, seeds "
                   f"{data['suite']['seeds'][0]}–{data['suite']['seeds'][-1]}; best heuristic: "
                   + ", ".join(f"{m} {n}" for m, n in block["best_heuristic"].items()) + ")\n")
        out.append("| controller | kind | RMSE ° | within 2° | energy J | budget exhausted | "
                   "vs best heuristic °, 95 % CI |")
        out.append("|---|---|---:|---:|---:|---:|---|")
        for c in block["controllers"]:
            n = len(c["episodes"])
            out.append(f"| {c['name']} | {c['kind']} | {c['rmse_deg']:.2f} | "
                       f"{c['within_2deg_frac']:.3f} | {c['energy_J']:.0f} | "
                       f"{c['budget_exhausted_episodes']}/{n} | "
                       f"{format_paired(c['paired_vs_best_heuristic'])} |")
        out.append("")
    return "\n".join(out)


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
        description="Run the heuristic controllers, the MPC and any saved SB3 policy on fixed, "
                    "seeded suites of NeckTrack target trajectories (nominal, randomized plant, "
                    "catalogue effects) under one energy budget; print per-suite tables with "
                    "paired 95 %% bootstrap intervals against the best heuristic; write CSV, "
                    "JSON and a plot.",
        epilog="CSV columns: " + ", ".join(CSV_COLUMNS) + ". One row per controller per "
               "episode, then one aggregate row (episode = 'all'), per suite. See the module "
               "docstring (python -c 'import agents.benchmark as b; help(b)') for their "
               "definitions.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--controllers", default=",".join(DEFAULT_CONTROLLERS + ("policies",)),
                   help="comma-separated subset of " + ", ".join(sorted(CONTROLLERS))
                        + ", plus 'policies' (every saved policy in --policy-dir) or a policy's "
                          "file stem")
    p.add_argument("--env-id", choices=sorted(ENV_DEFAULTS), default="NeckTrack-v1",
                   help="the env whose defaults (budget, actuation) the suites use")
    p.add_argument("--suites", default=",".join(SUITES),
                   help="comma-separated subset of " + ", ".join(SUITES))
    p.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                   help="episodes per suite")
    p.add_argument("--seed", type=int, default=1000,
                   help="env reset seed of the first episode; episode i uses seed + i")
    p.add_argument("--episode-s", type=float, default=60.0, help="episode length in seconds")
    p.add_argument("--energy-budget", type=float, default=None,
                   help="energy budget per episode in J ('inf' for none; default: the env id's, "
                        "v1 900 J, v0 1500 J)")
    p.add_argument("--actuation", choices=("ideal", "firmware"), default=None,
                   help="actuation (default: the env id's, v1 firmware, v0 ideal)")
    p.add_argument("--action-mode", choices=("current", "relay", "both"), default="both",
                   help="action interface for the hand-written controllers ('both' runs each "
                        "twice; relay runs are named NAME@relay; the MPC runs in current mode "
                        "only unless --action-mode relay). Policies always use the mode they "
                        "were trained in")
    p.add_argument("--mpc-suites", default="nominal",
                   help="suites the MPC runs on (5 s per episode), comma-separated, or 'all'")
    p.add_argument("--policy-dir", type=Path, default=POLICY_DIR,
                   help="where to look for NAME.zip + NAME.json policies")
    p.add_argument("--quick", action="store_true",
                   help="smoke test: 1 episode of 10 s per suite (overrides --episodes and "
                        "--episode-s)")
    p.add_argument("--out-dir", type=Path, default=Path("runs/benchmark"),
                   help="directory for the default CSV, JSON and plot paths")
    p.add_argument("--csv", type=Path, default=None, help="CSV path (default OUT_DIR/benchmark.csv)")
    p.add_argument("--json", type=Path, default=None,
                   help="JSON path (default OUT_DIR/benchmark.json)")
    p.add_argument("--plot", type=Path, default=None,
                   help="PNG path of the first episode's theta/phi plot (default "
                        "OUT_DIR/benchmark.png)")
    p.add_argument("--no-plot", action="store_true", help="skip the plot")
    p.add_argument("--markdown", type=Path, default=None,
                   help="also write the tables as Markdown (the README's) to this path")
    add_ray_argument(p, "episodes")
    return p


def _split(text: str) -> list[str]:
    return [c.strip() for c in text.split(",") if c.strip()]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    episodes, episode_s = (1, 10.0) if args.quick else (args.episodes, args.episode_s)
    if episodes < 1:
        raise SystemExit("--episodes must be >= 1")
    suites = _split(args.suites)
    bad = [x for x in suites if x not in SUITES]
    if bad or not suites:
        raise SystemExit(f"unknown suite(s) {bad}; known: {SUITES}")
    mpc_suites = suites if args.mpc_suites == "all" else _split(args.mpc_suites)
    env_defaults = ENV_DEFAULTS[args.env_id]
    budget = env_defaults["energy_budget_J"] if args.energy_budget is None else args.energy_budget
    actuation = args.actuation or env_defaults["actuation"]
    seeds = [args.seed + i for i in range(episodes)]
    modes = ("current", "relay") if args.action_mode == "both" else (args.action_mode,)
    wanted = _split(args.controllers)
    notes: list[str] = []
    policies, pol_notes = find_policies(args.policy_dir)
    by_stem = {p.stem: p for p in policies}
    unknown = [w for w in wanted if w not in CONTROLLERS and w not in by_stem and w != "policies"]
    if unknown:
        raise SystemExit(f"unknown controller(s) {unknown}; known: {sorted(CONTROLLERS)}, "
                         f"'policies', or a policy stem in {args.policy_dir} "
                         f"({sorted(by_stem) or 'none found'})")
    chosen = policies if "policies" in wanted else [by_stem[w] for w in wanted if w in by_stem]
    if "policies" in wanted or chosen:
        notes += pol_notes
        if not chosen:
            notes.append(f"no saved SB3 policy (NAME.zip + NAME.json) in {args.policy_dir}: "
                         "learned controllers skipped")
    base_kw = suite_env_kwargs(episode_s, budget, "current", actuation)

    def agents_for(suite: str) -> list[Agent]:
        out: list[Agent] = []
        for mode in modes:
            kw = suite_env_kwargs(episode_s, budget, mode, actuation)
            for name in wanted:
                if name not in CONTROLLERS:
                    continue
                if name == "mpc" and (suite not in mpc_suites
                                      or (mode == "relay" and len(modes) > 1)):
                    continue
                out.append(controller_agent(name, kw))
        for z in chosen:
            try:
                out.append(policy_agent(z, base_kw))
            except Exception as exc:  # a broken policy must not sink the benchmark
                msg = f"skipped policy {z.name}: {type(exc).__name__}: {exc}"
                if msg not in notes:
                    notes.append(msg)
        return out

    plan = {suite: agents_for(suite) for suite in suites}
    for n in notes:
        print(f"note: {n}")
    if not any(plan.values()):
        raise SystemExit("nothing to run")
    print(f"{args.env_id}: suites {', '.join(suites)}; {episodes} episode(s) x {episode_s:g} s "
          f"each, seeds {seeds[0]}..{seeds[-1]}, energy budget {budget:g} J, {actuation} "
          f"actuation")
    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    best: dict[str, dict[str, str]] = {}
    for suite in suites:
        res = run_suite(plan[suite], seeds, ray_address=args.ray, suite=suite)
        best[suite] = paired_vs_best_heuristic(res)
        results += res
    wall = time.perf_counter() - t0
    for suite in suites:
        print(f"\nsuite {suite}:")
        print(format_table([r for r in results if r["suite"] == suite], budget))
    suite_meta = {"env_id": args.env_id, "suites": suites, "seeds": seeds, "episode_s": episode_s,
                  "energy_budget_J": budget, "actuation": actuation, "action_modes": list(modes),
                  "mpc_suites": [s_ for s_ in mpc_suites if s_ in suites],
                  "effects_cycle": list(EFFECT_NAMES), "env_kwargs": base_kw,
                  "best_heuristic": best, "bootstrap": {"confidence": 0.95, "method": "BCa",
                                                        "resamples": BOOTSTRAP_RESAMPLES},
                  "wall_s": wall}
    csv_path = args.csv or args.out_dir / "benchmark.csv"
    json_path = args.json or args.out_dir / "benchmark.json"
    write_csv(csv_path, results)
    write_json(json_path, results, suite_meta, notes)
    print(f"\nwrote {csv_path} and {json_path}", end="")
    if not args.no_plot:
        plot_path = args.plot or args.out_dir / "benchmark.png"
        write_plot(plot_path, [r for r in results if r["suite"] == suites[0]])
        print(f" and {plot_path}", end="")
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown_tables(json.loads(json_path.read_text())))
        print(f" and {args.markdown}", end="")
    print(f" ({wall / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    # Run the importable module's main: Ray workers then find its functions by name.
    from agents.benchmark import main as _main

    sys.exit(_main())
