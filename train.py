"""Train a Stable-Baselines3 agent on NeckTrack-v0.

    python train.py --algo ppo                      # agents/configs/ppo.yml, seed 0
    python train.py --algo sac --seed 3 --n-timesteps 2e5
    python train.py --algo ppo --env-kwargs action_mode=relay --hyperparams learning_rate=1e-4
    python train.py --algo ppo --ship agents/policies/ppo_necktrack   # export the deployable policy

The experiment: read the config (rl-baselines3-zoo style YAML, one block per env id), build
the natively batched env (one compiled step for all rigs, see agents/sb3_env.py; the config
handling and the env/model construction are in agents/training.py, shared with the Ray Tune
sweep agents/sweep.py), wrap it (episode statistics, observation/reward normalization, frame
stacking), train with evaluation and checkpoint callbacks, save. Everything lands in --out
(created once the config, env and model are built, so a bad argument leaves no folder):

    model.zip  vecnormalize.pkl (with normalize)  config.yml (the exact configuration, seed,
    versions and wall time)  policy.zip + policy.json (deployable:
    agents.policy.DeployedPolicy.load)  tb/ (TensorBoard, unless --no-tensorboard)
    best_model.zip + evaluations.npz  once an evaluation has run (every --eval-freq steps)
    checkpoints/                      once a checkpoint is due (every --save-freq steps)

SB3 collects whole rollouts, so a run takes --n-timesteps rounded up to a multiple of
n_steps x n_envs (PPO, A2C) or train_freq x n_envs (SAC, TD3); the run says so, and the
progress bar counts to that number.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from agents.training import (ALGOS, CONFIG_DIR, build_model, load_config, make_env, parse_kv,
                             resolve_config, rollout_steps, vecnormalize_of)


def run_progress_bar(total_steps: int):
    """SB3's progress bar, counting to the steps the run really takes (SB3's own counts to the
    requested number and overshoots it)."""
    from stable_baselines3.common.callbacks import ProgressBarCallback
    from tqdm.rich import tqdm

    class _Bar(ProgressBarCallback):
        def _on_training_start(self) -> None:
            self.pbar = tqdm(total=total_steps - self.model.num_timesteps)

    return _Bar()


class ProgressLines:
    """Without the progress bar (a log file): one line per rollout at most every 30 s -- steps,
    rate, elapsed, and the mean reward per step of the training episodes finished lately (the
    env's -tracking error in deg; -e^2/10 with a residual's ``squared_error``)."""

    def __new__(cls, total_steps: int, n_envs: int):
        from stable_baselines3.common.callbacks import BaseCallback

        class _Lines(BaseCallback):
            def _on_training_start(self) -> None:
                self.t0 = self.last = time.time()

            def _on_step(self) -> bool:
                return True

            def _on_rollout_end(self) -> None:
                now = time.time()
                if now - self.last < 30.0:
                    return
                self.last = now
                eps = list(self.model.ep_info_buffer)
                err = (f", mean reward per step of the last {len(eps)} episodes "
                       f"{np.mean([e['r'] / e['l'] for e in eps]):.3f}" if eps else "")
                n = self.model.num_timesteps
                print(f"  {n:>10,}/{total_steps:,} steps, {n / (now - self.t0):,.0f} steps/s, "
                      f"{(now - self.t0) / 60:.1f} min{err}", flush=True)

        return _Lines()


def write_curve(out: Path, record: dict) -> list[Path]:
    """The evaluation curve (EvalCallback's evaluations.npz) as CSV and PNG: env steps against
    the mean tracking error of the evaluation episodes (deg; reward = -error per step)."""
    path = out / "evaluations.npz"
    if not path.exists():
        return []
    d = dict(np.load(path))
    start = out / "evaluation_at_start.npz"
    if start.exists():
        s0 = np.load(start)
        d = {k: np.concatenate([s0[k], d[k]]) for k in ("timesteps", "results", "ep_lengths")}
    err = -d["results"].mean(axis=1) / d["ep_lengths"].mean(axis=1)
    csv_path = out / "curve.csv"
    csv_path.write_text("timesteps,mean_tracking_error_deg\n" + "".join(
        f"{t},{e:.4f}\n" for t, e in zip(d["timesteps"], err)))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(d["timesteps"], err, "o-")
    ax.set_xlabel("env steps")
    ax.set_ylabel("mean tracking error (deg)")
    ax.set_title(f"{record['algo']} on {record['env_id']}, seed {record['seed']}: evaluation "
                 f"episodes", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    png = out / "curve.png"
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return [csv_path, png]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=ALGOS, default="ppo", help="SB3 algorithm (default: ppo)")
    ap.add_argument("--env", default="NeckTrack-v0", help="env id; selects the block of the config")
    ap.add_argument("--config", type=Path, default=None,
                    help="YAML hyperparameters (default: agents/configs/<algo>.yml)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the envs, the networks and SB3")
    ap.add_argument("--n-timesteps", type=float, default=None,
                    help="override the config's n_timesteps (rounded up to whole rollouts)")
    ap.add_argument("--n-envs", type=int, default=None, help="override the config's n_envs (rigs per step)")
    ap.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE",
                    help="NeckTrack-v0 keyword overrides, e.g. action_mode=relay energy_budget_J=1000")
    ap.add_argument("--hyperparams", nargs="*", default=[], metavar="KEY=VALUE",
                    help="algorithm keyword overrides, e.g. learning_rate=1e-4 gamma=0.99")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: runs/<algo>_seed<seed>)")
    ap.add_argument("--eval-freq", type=int, default=50_000,
                    help="evaluate every this many env steps (summed over envs); 0 = never")
    ap.add_argument("--eval-episodes", type=int, default=8, help="episodes per evaluation")
    ap.add_argument("--save-freq", type=int, default=500_000,
                    help="checkpoint every this many env steps (summed over envs); 0 = never")
    ap.add_argument("--tensorboard", action=argparse.BooleanOptionalAction, default=True,
                    help="write TensorBoard logs to <out>/tb (default: on)")
    ap.add_argument("--progress-bar", action=argparse.BooleanOptionalAction, default=True,
                    help="show a progress bar up to the steps the run really takes (default: on)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch CPU threads (default: 1: small MLPs gain nothing from more, and on "
                         "a busy 2-core machine spinning OpenMP threads slowed PPO 30-fold)")
    ap.add_argument("--ship", type=Path, default=None,
                    help="also export the deployable policy to this path (.zip + .json)")
    ap.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import stable_baselines3 as sb3
    import torch
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback

    from agents.policy import export

    config_path = args.config or CONFIG_DIR / f"{args.algo}.yml"
    cfg = load_config(config_path, args.env)
    cfg.setdefault("env_kwargs", {})
    # the env id's own defaults (NeckTrack-v1: its budget and actuation), then the config's,
    # then the command line's
    import gymnasium as gym

    import neck_env  # noqa: F401  (registers the ids)

    spec_kwargs = dict(gym.spec(args.env).kwargs)
    cfg["env_kwargs"] = {**spec_kwargs, **cfg["env_kwargs"],
                         **parse_kv(args.env_kwargs, "--env-kwargs")}
    cfg.update(parse_kv(args.hyperparams, "--hyperparams"))
    if args.n_timesteps is not None:
        cfg["n_timesteps"] = args.n_timesteps
    if args.n_envs is not None:
        cfg["n_envs"] = args.n_envs
    run = resolve_config(cfg)
    cfg, n_envs, n_timesteps = run.cfg, run.n_envs, run.n_timesteps
    normalize, frame_stack, unit_actions = run.normalize, run.frame_stack, run.unit_actions

    out = args.out or Path("runs") / f"{args.algo}_seed{args.seed}"
    torch.set_num_threads(args.threads)

    # Everything that can reject an argument runs before the run folder exists.
    try:
        model, env = build_model(args.algo, run, args.seed,
                                 out / "tb" if args.tensorboard else None, args.verbose)
        eval_env = make_env(4, args.seed + 10_000, cfg["env_kwargs"], normalize, frame_stack,
                            False, unit_actions, run.gamma, run.residual)
    except (ValueError, TypeError) as exc:  # a bad --env-kwargs / --hyperparams value
        raise SystemExit(f"train.py: {exc}") from None
    chunk = rollout_steps(model)
    steps = -(-n_timesteps // chunk) * chunk
    if steps != n_timesteps:
        print(f"note: {n_timesteps:,} steps requested; {args.algo.upper()} collects whole rollouts "
              f"of {chunk:,} env steps, so the run takes {steps:,}")
    out.mkdir(parents=True, exist_ok=True)

    callbacks = [run_progress_bar(steps)] if args.progress_bar else [ProgressLines(steps, n_envs)]
    if args.eval_freq > 0:
        callbacks.append(EvalCallback(eval_env, n_eval_episodes=args.eval_episodes,
                                      eval_freq=max(args.eval_freq // n_envs, 1),
                                      best_model_save_path=str(out), log_path=str(out),
                                      deterministic=True, verbose=args.verbose))
    if args.save_freq > 0:
        callbacks.append(CheckpointCallback(save_freq=max(args.save_freq // n_envs, 1),
                                            save_path=str(out / "checkpoints"), name_prefix="model",
                                            save_vecnormalize=normalize))

    if run.residual is not None and args.eval_freq > 0:
        # the untrained residual policy is the PID: its evaluation is the curve's first point
        from stable_baselines3.common.evaluation import evaluate_policy

        from agents.training import sync_normalization

        sync_normalization(env, eval_env)
        rewards, lengths = evaluate_policy(model, eval_env, n_eval_episodes=args.eval_episodes,
                                           deterministic=True, return_episode_rewards=True)
        np.savez(out / "evaluation_at_start.npz", timesteps=[0], results=[rewards],
                 ep_lengths=[lengths])
        print(f"  at start (the PID): mean tracking error "
              f"{-np.sum(rewards) / np.sum(lengths):.3f} deg over {len(rewards)} evaluation "
              f"episodes", flush=True)
    started = time.time()
    # total_timesteps stays as requested: the learning-rate schedules are fractions of it
    model.learn(total_timesteps=n_timesteps, callback=callbacks, tb_log_name=args.algo)
    wall = time.time() - started

    model.save(str(out / "model.zip"))
    vecnorm = vecnormalize_of(env, run)
    if vecnorm is not None:
        vecnorm.save(str(out / "vecnormalize.pkl"))
    record = {
        "algo": args.algo, "env_id": args.env, "seed": args.seed, "config_file": str(config_path),
        "config": cfg, "n_envs": n_envs, "n_timesteps": n_timesteps,
        "wall_time_s": round(wall, 1), "command": " ".join([sys.executable, *sys.argv]),
        "versions": {"python": platform.python_version(), "stable_baselines3": sb3.__version__,
                     "torch": str(torch.__version__), "numpy": np.__version__},
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads",
    }
    (out / "config.yml").write_text(yaml.safe_dump(record, sort_keys=False))
    trained = {k: record[k] for k in ("seed", "n_timesteps", "wall_time_s", "command", "versions")}
    export(model, out / "policy", args.algo, cfg["env_kwargs"], frame_stack, vecnorm, trained,
           unit_actions, args.env, run.residual)
    curve = write_curve(out, record)
    if args.ship is not None:
        shipped = export(model, args.ship, args.algo, cfg["env_kwargs"], frame_stack, vecnorm,
                         trained, unit_actions, args.env, run.residual)
        for src in curve:
            shutil.copy(src, shipped.with_name(f"{shipped.stem}.{src.name}"))
        print(f"shipped {shipped} (+ .json{', training curve' if curve else ''})")
    print(json.dumps({"out": str(out), "wall_time_s": round(wall, 1), "n_timesteps": n_timesteps}))
    shutil.rmtree(out / "tmp", ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
