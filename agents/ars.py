"""Augmented Random Search (Mania, Guy and Recht 2018, ARS V2-t) of a linear residual on a
controller: the PID (``base: pid``, the default) or bang-bang (``base: bang_bang``).

    python -m agents.ars agents/configs/ars_residual.yml --ship agents/policies/ars_residual_v1

Why ARS here: on ``NeckTrack-v1`` what the PID does badly is spending its 900 J -- running out
at 55 s costs the last seconds of the episode -- and that consequence comes up to a minute after
the currents that caused it. ARS scores whole episodes, so the credit for an early saving is
assigned exactly, and its objective can be the benchmark's own: the mean over episodes of the
squared tracking error (the pooled RMSE squared). Every candidate of an iteration runs on the
same episodes (common random numbers), so candidates are compared paired, as the benchmark
compares controllers.

The policy: ``r = clip(W f_norm + b, -1, 1)`` with ``f`` the residual features of
``agents.residual`` (observation, base currents, error integral, elapsed fraction) normalized by
running statistics (ARS V2), and the current ``clip(base + scale_A r, 0, i_max)`` (relay mode:
sigma-delta encoded, as the heuristics do). W = 0, b = 0 is the base controller. All candidates x episodes of
an iteration advance together in one natively batched env.

Outputs (``--out``, default ``runs/ars_<name>``): ``policy.zip`` (the weights, an npz archive:
no pickles) + ``policy.json`` (``algo: "ARS"``, the residual, observation statistics, the
config, provenance) for ``agents.policy.DeployedPolicy``; ``curve.csv`` / ``curve.png``
(validation RMSE of the centre policy against the base's on the same episodes, per iteration);
``--ship PATH`` copies the policy and its curve there. Progress: one line per iteration.
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
from typing import Any

import numpy as np
import yaml

from .residual import BASES, N_FEATURES, ControllerResidual


@dataclass(frozen=True)
class ARSConfig:
    """One ARS run (the YAML file's keys)."""

    env_id: str = "NeckTrack-v1"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
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

    @classmethod
    def load(cls, path: Path) -> "ARSConfig":
        data = yaml.safe_load(Path(path).read_text()) or {}
        unknown = set(data) - {f for f in cls.__dataclass_fields__}
        if unknown:
            raise SystemExit(f"{path}: unknown key(s) {sorted(unknown)}")
        if "validation_seeds" in data:
            data["validation_seeds"] = tuple(data["validation_seeds"])
        cfg = cls(**data)
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


def rollout(task_kwargs: dict[str, Any], scale_A: float, W: np.ndarray, b: np.ndarray,
            seeds: list[int], mean: np.ndarray, std: np.ndarray,
            stats: RunningStats | None = None, base_name: str = "pid") -> np.ndarray:
    """Candidates ``W`` (C, 3, F), ``b`` (C, 3) on every seed: one batched env of C x len(seeds)
    rigs. Returns the mean squared tracking error per candidate and episode (C, E), deg^2."""
    from neck_env.envs import NeckTrackVectorEnv

    C, E = W.shape[0], len(seeds)
    n = C * E
    venv = NeckTrackVectorEnv(num_envs=n, **task_kwargs)
    base = ControllerResidual(task_kwargs, n, scale_A, base_name)
    obs, _ = venv.reset(seed=[s for _ in range(C) for s in seeds])
    core = venv.core
    cand = np.repeat(np.arange(C), E)
    Wn, bn = W[cand], b[cand]
    steps = venv.task.episode_steps
    sq = np.zeros(n)
    for _ in range(steps):
        f = base.features(obs)
        if stats is not None:
            stats.update(f)
        x = (f - mean) / std
        r = np.clip(np.einsum("nkf,nf->nk", Wn, x) + bn, -1.0, 1.0)
        core.step(venv.task.currents_A(base.actions(r), n))
        obs = core.obs
        sq += core.err ** 2
    return (sq / steps).reshape(C, E)


def train(cfg: ARSConfig, out: Path, log=print) -> dict[str, Any]:
    task_kwargs = cfg.task_kwargs()
    rng = np.random.default_rng(cfg.seed)
    F = N_FEATURES
    W, b = np.zeros((3, F)), np.zeros(3)
    stats = RunningStats(F)
    val = list(cfg.validation_seeds)
    t0 = time.time()
    # the base controller (W = 0) on the validation episodes: the reference of the curve; it
    # also seeds the feature statistics
    base_val = rollout(task_kwargs, cfg.scale_A, W[None], b[None], val, np.zeros(F), np.ones(F),
                      stats, cfg.base)[0]
    log(f"{cfg.base} on {len(val)} validation episodes: RMSE {np.sqrt(base_val.mean()):.3f} deg "
        f"({time.time() - t0:.0f} s)")
    curve = [(0, float(np.sqrt(base_val.mean())), float(np.sqrt(base_val.mean())), 0.0)]
    best = (float(base_val.mean()), W.copy(), b.copy(), stats.mean.copy(), stats.std().copy(), 0)
    for it in range(1, cfg.iterations + 1):
        mean, std = stats.mean.copy(), stats.std().copy()
        dW = rng.standard_normal((cfg.directions, 3, F))
        db = rng.standard_normal((cfg.directions, 3))
        seeds = [int(s) for s in rng.integers(10_000, 2**31 - 1, cfg.episodes_per_candidate)]
        Wc = np.concatenate([W + cfg.noise_std * dW, W - cfg.noise_std * dW])
        bc = np.concatenate([b + cfg.noise_std * db, b - cfg.noise_std * db])
        mse = rollout(task_kwargs, cfg.scale_A, Wc, bc, seeds, mean, std, stats, cfg.base)
        reward = -mse.mean(axis=1)  # objective: minus the pooled squared error
        r_plus, r_minus = reward[:cfg.directions], reward[cfg.directions:]
        top = np.argsort(-np.maximum(r_plus, r_minus))[:cfg.top_directions]
        sigma = np.concatenate([r_plus[top], r_minus[top]]).std()
        sigma = sigma if sigma > 1e-12 else 1.0
        step = cfg.step_size / (cfg.top_directions * sigma)
        W = W + step * np.einsum("k,kij->ij", r_plus[top] - r_minus[top], dW[top])
        b = b + step * (r_plus[top] - r_minus[top]) @ db[top]
        line = (f"iteration {it}/{cfg.iterations}: candidates RMSE {np.sqrt(mse.mean(axis=1)).min():.3f}"
                f"-{np.sqrt(mse.mean(axis=1)).max():.3f} deg")
        if it % cfg.validate_every == 0 or it == cfg.iterations:
            v = rollout(task_kwargs, cfg.scale_A, W[None], b[None], val, stats.mean, stats.std(),
                        base_name=cfg.base)[0]
            d = np.sqrt(v) - np.sqrt(base_val)
            curve.append((it, float(np.sqrt(v.mean())), float(np.sqrt(base_val.mean())),
                          float(d.mean())))
            line += (f"; validation RMSE {np.sqrt(v.mean()):.3f} deg ({cfg.base} {np.sqrt(base_val.mean()):.3f}"
                     f", paired mean {d.mean():+.3f}, better in {int((d < 0).sum())}/{len(val)})")
            if v.mean() < best[0]:
                best = (float(v.mean()), W.copy(), b.copy(), stats.mean.copy(), stats.std().copy(), it)
        log(f"{line} ({(time.time() - t0) / 60:.1f} min)")
    wall = time.time() - t0
    _, Wb, bb, mb, sb, it_best = best
    out.mkdir(parents=True, exist_ok=True)
    _write_curve(out, curve, cfg.base)
    meta = export(out / "policy", Wb, bb, mb, sb, cfg, task_kwargs, {
        "seed": cfg.seed, "iterations": cfg.iterations, "chosen_iteration": it_best,
        "wall_time_s": round(wall, 1), "command": " ".join([sys.executable, *sys.argv]),
        "versions": {"python": platform.python_version(), "numpy": np.__version__}})
    log(f"chose iteration {it_best} (best validation RMSE); {wall / 60:.1f} min")
    return meta


def export(path: Path, W, b, mean, std, cfg: ARSConfig, task_kwargs: dict[str, Any],
           trained: dict[str, Any]) -> dict[str, Any]:
    """``path``.zip (weights) + ``path``.json for ``agents.policy.DeployedPolicy``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    LinearResidual(W, b).save(path.with_suffix(".zip"))
    env_kwargs = {k: v for k, v in task_kwargs.items() if k != "episode_s"}
    meta = {"algo": "ARS", "env_id": cfg.env_id, "env_kwargs": env_kwargs, "frame_stack": 1,
            "unit_actions": False,
            # DeployedPolicy's normalization: (x - mean) / sqrt(var + epsilon), clipped
            "obs_norm": {"mean": list(map(float, mean)), "var": list(map(float, std ** 2)),
                         "clip": 1e9, "epsilon": 0.0},
            "residual": {"base": cfg.base, "scale_A": cfg.scale_A},
            "config": {**asdict(cfg), "validation_seeds": list(cfg.validation_seeds)},
            "trained": trained}
    path.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return meta


def _write_curve(out: Path, curve: list[tuple], base: str = "pid") -> None:
    (out / "curve.csv").write_text(f"iteration,validation_rmse_deg,{base}_rmse_deg,paired_mean_diff_deg\n"
                                   + "".join(f"{i},{v:.4f},{p:.4f},{d:.4f}\n" for i, v, p, d in curve))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = [c[0] for c in curve]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(it, [c[1] for c in curve], "o-", label="ARS residual (centre policy)")
    ax.plot(it, [c[2] for c in curve], "k--", label=base)
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
