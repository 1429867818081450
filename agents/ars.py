"""Augmented Random Search (Mania, Guy and Recht 2018, ARS V2-t) of a small policy for
``NeckTrack-v1``: the muscle-shared law (``policy: muscle``, ``agents.muscle_policy``; the shipped
v1 policies) or a linear residual on a controller (``policy: residual``: the PID, ``base: pid``,
or bang-bang, ``base: bang_bang``).

    python -m agents.ars agents/configs/ars_muscle.yml --ship agents/policies/ars_muscle_v1

Why ARS here: on ``NeckTrack-v1`` what decides the score is how the 900 J are spent -- running
out at 55 s costs the last seconds of the episode -- and that consequence comes up to a minute
after the currents that caused it. ARS scores whole episodes, so the credit for an early saving
is assigned exactly, and its objective can be the benchmark's own: the mean over episodes of the
squared tracking error (the pooled RMSE squared), plus, if the config says so, a cost per step
spent more than 2 deg off (``outside_weight_deg2``). Every candidate of an iteration runs on the
same episodes (common random numbers), so candidates are compared paired, as the benchmark
compares controllers; the episodes cycle through the benchmark's suites the config names
(``train_suites``: nominal, randomized plant, catalogue effects).

The policies: the muscle law ``a_k = sigmoid(3/deg (p_k - 1 deg) + w . phi_k)`` (w = 0: a
smoothed bang-bang; see ``agents.muscle_policy``), or the residual ``r = clip(W f_norm + b, -1,
1)`` with ``f`` the features of ``agents.residual`` normalized by running statistics (ARS V2)
and the current ``clip(base + scale_A r, 0, i_max)`` (W = 0, b = 0: the base controller).
Relay mode: sigma-delta encoded, as the heuristics do. All candidates x episodes of an iteration
advance together in natively batched envs (one per suite group).

Outputs (``--out``, default ``runs/ars_<name>``): ``policy.zip`` (the weights, an npz archive:
no pickles) + ``policy.json`` (``algo: "ARS"``, the policy kind, observation statistics, the
config, provenance) for ``agents.policy.DeployedPolicy``; ``curve.csv`` / ``curve.png``
(validation RMSE and time within 2 deg of the centre policy against the untrained one on the
same episodes, per validated iteration); ``--ship PATH`` copies the policy and its curve there.
Progress: one line per iteration.
"""

from __future__ import annotations

import argparse
import io
import json
import platform
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from .benchmark import SUITES, WITHIN_DEG, suite_overrides
from .muscle_policy import FEATURES as MUSCLE_FEATURE_NAMES
from .muscle_policy import N_FEATURES as MUSCLE_FEATURES
from .muscle_policy import MusclePolicy, MuscleWeights
from .residual import BASES, N_FEATURES, ControllerResidual

POLICIES = ("residual", "muscle")


@dataclass(frozen=True)
class ARSConfig:
    """One ARS run (the YAML file's keys)."""

    env_id: str = "NeckTrack-v1"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    # "residual": a linear residual on ``base``; "muscle": the muscle-shared law
    # (agents.muscle_policy; base and scale_A unused)
    policy: str = "residual"
    base: str = "pid"  # the controller the residual corrects: "pid" or "bang_bang"
    scale_A: float = 3.0  # residual span, A
    iterations: int = 40
    directions: int = 8  # perturbation directions per iteration (each evaluated + and -)
    top_directions: int = 4  # the best directions used in the update
    step_size: float = 0.02
    noise_std: float = 0.03  # perturbation size in normalized-feature units
    episodes_per_candidate: int = 8  # common to every candidate of an iteration
    episode_s: float = 60.0
    validation_seeds: tuple[int, ...] = tuple(range(5000, 5016))  # not the benchmark's 1000+
    validate_every: int = 5
    seed: int = 0
    # objective per step: e^2 + outside_weight_deg2 * [e > 2 deg] (0: the benchmark's RMSE^2
    # alone; > 0 also buys time within 2 deg, which RMSE trades away for faster transients)
    outside_weight_deg2: float = 0.0
    # the benchmark suites the training episodes cycle through (domain randomization)
    train_suites: tuple[str, ...] = ("nominal",)

    @classmethod
    def load(cls, path: Path) -> "ARSConfig":
        data = yaml.safe_load(Path(path).read_text()) or {}
        unknown = set(data) - {f for f in cls.__dataclass_fields__}
        if unknown:
            raise SystemExit(f"{path}: unknown key(s) {sorted(unknown)}")
        for key in ("validation_seeds", "train_suites"):
            if key in data:
                data[key] = tuple(data[key])
        cfg = cls(**data)
        if cfg.policy not in POLICIES:
            raise SystemExit(f"{path}: policy {cfg.policy!r} is not one of {POLICIES}")
        bad = [x for x in cfg.train_suites if x not in SUITES]
        if bad or not cfg.train_suites:
            raise SystemExit(f"{path}: train_suites {list(cfg.train_suites)}: each one of {SUITES}")
        if cfg.outside_weight_deg2 < 0:
            raise SystemExit(f"{path}: outside_weight_deg2 must be >= 0")
        if cfg.base not in BASES:
            raise SystemExit(f"{path}: base {cfg.base!r} is not one of {sorted(BASES)}")
        if not (1 <= cfg.top_directions <= cfg.directions):
            raise SystemExit("need 1 <= top_directions <= directions")
        return cfg

    def task_kwargs(self) -> dict[str, Any]:
        import gymnasium as gym

        import neck_env  # noqa: F401  (registers the ids)

        return {**gym.spec(self.env_id).kwargs, **self.env_kwargs, "episode_s": self.episode_s}


class LinearResidual:
    """``predict`` like an SB3 model: normalized features (n, 14) or (14,) -> residual in [-1, 1]."""

    def __init__(self, W: np.ndarray, b: np.ndarray):
        self.W = np.asarray(W, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)

    def predict(self, x, deterministic: bool = True):
        x = np.asarray(x, dtype=np.float64)
        return np.clip(x @ self.W.T + self.b, -1.0, 1.0).astype(np.float32), None

    @classmethod
    def load(cls, path: str | Path) -> "LinearResidual":
        with np.load(path) as d:
            return cls(d["W"], d["b"])

    def save(self, path: str | Path) -> None:
        buf = io.BytesIO()
        np.savez(buf, W=self.W, b=self.b)
        Path(path).write_bytes(buf.getvalue())


class RunningStats:
    """Feature mean / variance over every state visited (ARS V2's state normalization)."""

    def __init__(self, dim: int):
        self.n = 0
        self.mean = np.zeros(dim)
        self.m2 = np.zeros(dim)

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.mean.size)
        k = x.shape[0]
        if k == 0:
            return
        mean_b, m2_b = x.mean(axis=0), x.var(axis=0) * k
        delta = mean_b - self.mean
        tot = self.n + k
        self.mean = self.mean + delta * k / tot
        self.m2 = self.m2 + m2_b + delta ** 2 * self.n * k / tot
        self.n = tot

    @property
    def var(self) -> np.ndarray:
        return self.m2 / self.n if self.n > 1 else np.ones_like(self.mean)

    def std(self) -> np.ndarray:
        # features that never vary (e.g. an unused muscle) are left unscaled
        s = np.sqrt(self.var)
        return np.where(s > 1e-8, s, 1.0)


def _groups(overrides: Sequence[Mapping[str, Any]]) -> list[tuple[dict[str, Any], list[int]]]:
    """Episode indices grouped by their simulation overrides (one batched env per group)."""
    out: dict[str, tuple[dict[str, Any], list[int]]] = {}
    for i, o in enumerate(overrides):
        out.setdefault(json.dumps(o, sort_keys=True), (dict(o), []))[1].append(i)
    return list(out.values())


def play(task_kwargs: dict[str, Any], n_candidates: int, seeds: Sequence[int],
         make_agent: Callable[[int, np.ndarray], Any],
         overrides: Sequence[Mapping[str, Any]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate on every episode, candidates x episodes of one override advancing together
    in one natively batched env. ``make_agent(n, candidate_of_rig)`` returns an object with
    ``act(obs (n, 8)) -> env actions (n, 3)`` (fresh per env: its episodes start now).
    Returns per candidate and episode (C, E) the mean squared tracking error (deg^2) and the
    fraction of steps more than ``WITHIN_DEG`` off."""
    from neck_env.envs import NeckTrackVectorEnv

    E = len(seeds)
    overrides = [{}] * E if overrides is None else list(overrides)
    if len(overrides) != E:
        raise ValueError(f"{len(overrides)} overrides for {E} episodes")
    mse, outside = np.zeros((n_candidates, E)), np.zeros((n_candidates, E))
    for over, idx in _groups(overrides):
        n = n_candidates * len(idx)
        venv = NeckTrackVectorEnv(num_envs=n, **task_kwargs, **over)
        obs, _ = venv.reset(seed=[int(seeds[i]) for _ in range(n_candidates) for i in idx])
        agent = make_agent(n, np.repeat(np.arange(n_candidates), len(idx)))
        core, steps = venv.core, venv.task.episode_steps
        sq, off = np.zeros(n), np.zeros(n)
        for _ in range(steps):
            core.step(venv.task.currents_A(agent.act(obs), n))
            obs = core.obs
            sq += core.err ** 2
            off += core.err > WITHIN_DEG
        mse[:, idx] = (sq / steps).reshape(n_candidates, len(idx))
        outside[:, idx] = (off / steps).reshape(n_candidates, len(idx))
    return mse, outside


class _ResidualAgent:
    """The linear residual on a base controller (candidate rows ``Wn``, ``bn``), batched."""

    def __init__(self, task_kwargs, n, scale_A, base_name, Wn, bn, mean, std, stats):
        self.base = ControllerResidual(task_kwargs, n, scale_A, base_name)
        self.Wn, self.bn, self.mean, self.std, self.stats = Wn, bn, mean, std, stats

    def act(self, obs):
        f = self.base.features(obs)
        if self.stats is not None:
            self.stats.update(f)
        x = (f - self.mean) / self.std
        r = np.clip(np.einsum("nkf,nf->nk", self.Wn, x) + self.bn, -1.0, 1.0)
        return self.base.actions(r)


def rollout(task_kwargs: dict[str, Any], scale_A: float, W: np.ndarray, b: np.ndarray,
            seeds: list[int], mean: np.ndarray, std: np.ndarray,
            stats: RunningStats | None = None, base_name: str = "pid") -> np.ndarray:
    """Residual candidates ``W`` (C, 3, F), ``b`` (C, 3) on every seed (nominal plant). Returns
    the mean squared tracking error per candidate and episode (C, E), deg^2."""
    return play(task_kwargs, W.shape[0], seeds,
                lambda n, cand: _ResidualAgent(task_kwargs, n, scale_A, base_name, W[cand],
                                               b[cand], mean, std, stats))[0]


class _Residual:
    """ARS's view of the residual policy: theta = (W (3, F), b (3)) flattened, with the running
    feature statistics of ARS V2."""

    def __init__(self, cfg: "ARSConfig", task_kwargs: dict[str, Any]):
        self.cfg, self.task_kwargs = cfg, task_kwargs
        self.reference = cfg.base  # what theta = 0 is
        self.size = 3 * N_FEATURES + 3
        self.stats = RunningStats(N_FEATURES)
        self.frozen = (np.zeros(N_FEATURES), np.ones(N_FEATURES))  # statistics the policy uses

    def begin_iteration(self) -> None:
        self.frozen = (self.stats.mean.copy(), self.stats.std().copy())

    def play(self, thetas, seeds, overrides=None, learn_stats=True):
        W = thetas[:, :3 * N_FEATURES].reshape(-1, 3, N_FEATURES)
        b = thetas[:, 3 * N_FEATURES:]
        mean, std = self.frozen
        stats = self.stats if learn_stats else None
        return play(self.task_kwargs, len(thetas), seeds,
                    lambda n, cand: _ResidualAgent(self.task_kwargs, n, self.cfg.scale_A,
                                                   self.cfg.base, W[cand], b[cand], mean, std,
                                                   stats), overrides)

    def export(self, path: Path, theta, snapshot, trained: dict[str, Any]) -> dict[str, Any]:
        W, b = theta[:3 * N_FEATURES].reshape(3, N_FEATURES), theta[3 * N_FEATURES:]
        mean, std = snapshot
        return export(path, W, b, mean, std, self.cfg, self.task_kwargs, trained)

    def snapshot(self):
        return self.frozen


class _Muscle:
    """ARS's view of the muscle-shared law (``agents.muscle_policy``): theta = its weights. The
    features are scaled by fixed physical units, so no running statistics."""

    reference = "smoothed bang-bang (w = 0)"  # what theta = 0 is

    def __init__(self, cfg: "ARSConfig", task_kwargs: dict[str, Any]):
        self.cfg, self.task_kwargs = cfg, task_kwargs
        self.size = MUSCLE_FEATURES

    def begin_iteration(self) -> None:
        pass

    def play(self, thetas, seeds, overrides=None, learn_stats=True):
        return play(self.task_kwargs, len(thetas), seeds,
                    lambda n, cand: MusclePolicy(self.task_kwargs, n, thetas[cand]), overrides)

    def export(self, path: Path, theta, snapshot, trained: dict[str, Any]) -> dict[str, Any]:
        return export_muscle(path, theta, self.cfg, self.task_kwargs, trained)

    def snapshot(self):
        return None


def train_overrides(cfg: "ARSConfig", rng: np.random.Generator, episodes: int) -> list[dict[str, Any]]:
    """The simulation overrides of one iteration's episodes: the config's suites in turn (the
    benchmark's definitions), the effects suite's catalogue entry from a random offset so every
    entry comes round."""
    offset = int(rng.integers(0, 1_000))
    k = len(cfg.train_suites)
    return [suite_overrides(cfg.train_suites[i % k], offset + i // k) for i in range(episodes)]


def train(cfg: ARSConfig, out: Path, log=print) -> dict[str, Any]:
    task_kwargs = cfg.task_kwargs()
    rng = np.random.default_rng(cfg.seed)
    fam = _Muscle(cfg, task_kwargs) if cfg.policy == "muscle" else _Residual(cfg, task_kwargs)
    theta = np.zeros(fam.size)
    lam = cfg.outside_weight_deg2
    val = list(cfg.validation_seeds)
    t0 = time.time()
    # the untrained policy (theta = 0: the base controller) on the validation episodes: the
    # reference of the curve; for the residual it also seeds the feature statistics
    base_mse, base_out = (a[0] for a in fam.play(theta[None], val))
    base_rmse = float(np.sqrt(base_mse.mean()))
    log(f"{fam.reference} on {len(val)} validation episodes: RMSE {base_rmse:.3f} deg, within "
        f"{WITHIN_DEG:g} deg {1 - base_out.mean():.3f} ({time.time() - t0:.0f} s)")
    curve = [(0, base_rmse, base_rmse, 0.0, float(1 - base_out.mean()))]
    best = (float((base_mse + lam * base_out).mean()), theta.copy(), fam.snapshot(), 0)
    for it in range(1, cfg.iterations + 1):
        fam.begin_iteration()
        d = rng.standard_normal((cfg.directions, fam.size))
        seeds = [int(s) for s in rng.integers(10_000, 2**31 - 1, cfg.episodes_per_candidate)]
        over = train_overrides(cfg, rng, cfg.episodes_per_candidate)
        mse, outside = fam.play(np.concatenate([theta + cfg.noise_std * d, theta - cfg.noise_std * d]),
                                seeds, over)
        reward = -(mse + lam * outside).mean(axis=1)  # objective: the pooled squared error (+ time off)
        r_plus, r_minus = reward[:cfg.directions], reward[cfg.directions:]
        top = np.argsort(-np.maximum(r_plus, r_minus))[:cfg.top_directions]
        sigma = np.concatenate([r_plus[top], r_minus[top]]).std()
        sigma = sigma if sigma > 1e-12 else 1.0
        theta = theta + cfg.step_size / (cfg.top_directions * sigma) * ((r_plus[top] - r_minus[top]) @ d[top])
        line = (f"iteration {it}/{cfg.iterations}: candidates RMSE {np.sqrt(mse.mean(axis=1)).min():.3f}"
                f"-{np.sqrt(mse.mean(axis=1)).max():.3f} deg")
        if it % cfg.validate_every == 0 or it == cfg.iterations:
            fam.begin_iteration()  # validate with the statistics the policy would ship with
            v, v_out = (a[0] for a in fam.play(theta[None], val, learn_stats=False))
            diff = np.sqrt(v) - np.sqrt(base_mse)
            curve.append((it, float(np.sqrt(v.mean())), base_rmse, float(diff.mean()),
                          float(1 - v_out.mean())))
            line += (f"; validation RMSE {np.sqrt(v.mean()):.3f} deg ({fam.reference} {base_rmse:.3f}"
                     f", paired mean {diff.mean():+.3f}, better in {int((diff < 0).sum())}/{len(val)}"
                     f", within {WITHIN_DEG:g} deg {1 - v_out.mean():.3f})")
            score = float((v + lam * v_out).mean())
            if score < best[0]:
                best = (score, theta.copy(), fam.snapshot(), it)
        log(f"{line} ({(time.time() - t0) / 60:.1f} min)")
    wall = time.time() - t0
    _, theta_best, snap, it_best = best
    out.mkdir(parents=True, exist_ok=True)
    _write_curve(out, curve, fam.reference)
    meta = fam.export(out / "policy", theta_best, snap, {
        "seed": cfg.seed, "iterations": cfg.iterations,
        "chosen_iteration": it_best, "wall_time_s": round(wall, 1),
        "command": " ".join([sys.executable, *sys.argv]),
        "versions": {"python": platform.python_version(), "numpy": np.__version__}})
    log(f"chose iteration {it_best} (best validation objective); {wall / 60:.1f} min")
    return meta


def export(path: Path, W, b, mean, std, cfg: ARSConfig, task_kwargs: dict[str, Any],
           trained: dict[str, Any]) -> dict[str, Any]:
    """A residual policy: ``path``.zip (weights) + ``path``.json for
    ``agents.policy.DeployedPolicy``."""
    # DeployedPolicy's normalization: (x - mean) / sqrt(var + epsilon), clipped
    norm = {"mean": list(map(float, mean)), "var": list(map(float, std ** 2)), "clip": 1e9,
            "epsilon": 0.0}
    return _write(path, LinearResidual(W, b), cfg, task_kwargs, trained, norm,
                  residual={"base": cfg.base, "scale_A": cfg.scale_A})


def export_muscle(path: Path, w, cfg: ARSConfig, task_kwargs: dict[str, Any],
                  trained: dict[str, Any]) -> dict[str, Any]:
    """A muscle-shared policy: ``path``.zip (its weights) + ``path``.json."""
    return _write(path, MuscleWeights(w), cfg, task_kwargs, trained, None,
                  muscle={"features": list(MUSCLE_FEATURE_NAMES)})


def _write(path: Path, weights, cfg: ARSConfig, task_kwargs: dict[str, Any],
           trained: dict[str, Any], obs_norm: dict[str, Any] | None,
           **kind: dict[str, Any]) -> dict[str, Any]:
    """An ARS policy on disk: ``weights.save`` to ``path``.zip and its ``path``.json; ``kind``:
    ``residual=...`` or ``muscle=...``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    weights.save(path.with_suffix(".zip"))
    env_kwargs = {k: v for k, v in task_kwargs.items() if k != "episode_s"}
    meta = {"algo": "ARS", "env_id": cfg.env_id, "env_kwargs": env_kwargs, "frame_stack": 1,
            "unit_actions": False, "obs_norm": obs_norm, **kind,
            "config": _config_json(cfg), "trained": trained}
    path.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return meta


def _config_json(cfg: ARSConfig) -> dict[str, Any]:
    return {**asdict(cfg), "validation_seeds": list(cfg.validation_seeds),
            "train_suites": list(cfg.train_suites)}


def _write_curve(out: Path, curve: list[tuple], reference: str) -> None:
    """curve.csv / curve.png: the centre policy on the validation episodes per validated
    iteration, against ``reference`` (the untrained policy) on the same episodes."""
    (out / "curve.csv").write_text(
        "iteration,validation_rmse_deg,reference_rmse_deg,paired_mean_diff_deg,validation_within_2deg\n"
        + "".join(f"{i},{v:.4f},{p:.4f},{d:.4f},{w:.4f}\n" for i, v, p, d, w in curve))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [c[0] for c in curve]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(it, [c[1] for c in curve], "o-", label="ARS (centre policy)")
    ax.plot(it, [c[2] for c in curve], "k--", label=f"reference: {reference}")
    ax.set_xlabel("ARS iteration")
    ax.set_ylabel("validation RMSE (deg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "curve.png", dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m agents.ars", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", type=Path, help="YAML file of ARSConfig keys")
    ap.add_argument("--out", type=Path, default=None, help="run folder (default runs/ars_<stem>)")
    ap.add_argument("--iterations", type=int, default=None, help="override the config's")
    ap.add_argument("--ship", type=Path, default=None,
                    help="also copy the policy (.zip + .json) and its curve to this path")
    args = ap.parse_args(argv)
    cfg = ARSConfig.load(args.config)
    if args.iterations is not None:
        cfg = ARSConfig(**{**asdict(cfg), "iterations": args.iterations})
    out = args.out or Path("runs") / f"ars_{args.config.stem}"
    import torch  # noqa: F401  (only to pin its threads if installed: PID and env are numpy)

    torch.set_num_threads(1)
    train(cfg, out, log=lambda s: print(s, flush=True))
    if args.ship is not None:
        args.ship.parent.mkdir(parents=True, exist_ok=True)
        for suffix in (".zip", ".json"):
            shutil.copy(out / f"policy{suffix}", args.ship.with_suffix(suffix))
        for name in ("curve.csv", "curve.png"):
            shutil.copy(out / name, args.ship.with_name(f"{args.ship.name}.{name}"))
        print(f"shipped {args.ship.with_suffix('.zip')} (+ .json, training curve)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
