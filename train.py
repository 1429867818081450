"""Train a Stable-Baselines3 agent on NeckTrack-v0.

    python train.py --algo ppo                      # agents/configs/ppo.yml, seed 0
    python train.py --algo sac --seed 3 --n-timesteps 2e5
    python train.py --algo ppo --env-kwargs action_mode=relay --hyperparams learning_rate=1e-4
    python train.py --algo ppo --ship agents/policies/ppo_necktrack   # export the deployable policy

The whole experiment is in this file: read the config (rl-baselines3-zoo style YAML, one block
per env id), build the natively batched env (one compiled step for all rigs, see
agents/sb3_env.py), wrap it (episode statistics, observation/reward normalization, frame
stacking), train with evaluation and checkpoint callbacks, save. Everything lands in --out:

    model.zip  best_model.zip  checkpoints/  vecnormalize.pkl  evaluations.npz
    config.yml (the exact configuration, seed, versions and wall time)   tb/ (TensorBoard)
    policy.zip + policy.json (deployable: agents.policy.DeployedPolicy.load)
"""

from __future__ import annotations

import argparse
import ast
import json
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ALGOS = ("ppo", "sac", "a2c", "td3")
# Keys of a config block that configure the run, not the algorithm's constructor.
RUN_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "frame_stack", "unit_actions",
            "env_kwargs")


def parse_kv(items: list[str], what: str) -> dict[str, Any]:
    """``key=value`` pairs; values are Python literals when they parse as one, else strings."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"{what}: expected key=value, got {item!r}")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def load_config(path: Path, env_id: str) -> dict[str, Any]:
    if not path.exists():
        raise SystemExit(f"config {path} not found")
    data = yaml.safe_load(path.read_text()) or {}
    if env_id not in data:
        raise SystemExit(f"config {path} has no block for {env_id!r} (has {sorted(data)})")
    return dict(data[env_id])


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=ALGOS, default="ppo", help="SB3 algorithm (default: ppo)")
    ap.add_argument("--env", default="NeckTrack-v0", help="env id; selects the block of the config")
    ap.add_argument("--config", type=Path, default=None,
                    help="YAML hyperparameters (default: agents/configs/<algo>.yml)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the envs, the networks and SB3")
    ap.add_argument("--n-timesteps", type=float, default=None, help="override the config's n_timesteps")
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
                    help="show a progress bar (default: on)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch CPU threads (default: 1: small MLPs gain nothing from more, and on "
                         "a busy 2-core machine spinning OpenMP threads slowed PPO 30-fold)")
    ap.add_argument("--ship", type=Path, default=None,
                    help="also export the deployable policy to this path (.zip + .json)")
    ap.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")
    return ap


def make_env(n_envs: int, seed: int, env_kwargs: dict[str, Any], normalize: bool,
             frame_stack: int, training: bool, unit_actions: bool):
    from stable_baselines3.common.vec_env import VecFrameStack, VecMonitor, VecNormalize

    from agents.sb3_env import NeckTrackSB3VecEnv

    venv = VecMonitor(NeckTrackSB3VecEnv(n_envs, seed=seed, unit_actions=unit_actions, **env_kwargs))
    if normalize:
        venv = VecNormalize(venv, training=training, norm_obs=True, norm_reward=training,
                            gamma=0.995)
    if frame_stack > 1:
        venv = VecFrameStack(venv, frame_stack)
    return venv


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import stable_baselines3 as sb3
    import torch
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize, unwrap_vec_wrapper

    from agents.policy import export

    config_path = args.config or Path(__file__).parent / "agents" / "configs" / f"{args.algo}.yml"
    cfg = load_config(config_path, args.env)
    cfg.setdefault("env_kwargs", {})
    cfg["env_kwargs"] = {**cfg["env_kwargs"], **parse_kv(args.env_kwargs, "--env-kwargs")}
    cfg.update(parse_kv(args.hyperparams, "--hyperparams"))
    if args.n_timesteps is not None:
        cfg["n_timesteps"] = args.n_timesteps
    if args.n_envs is not None:
        cfg["n_envs"] = args.n_envs
    n_envs, n_timesteps = int(cfg["n_envs"]), int(float(cfg["n_timesteps"]))
    normalize, frame_stack = bool(cfg.get("normalize", False)), int(cfg.get("frame_stack", 1))
    unit_actions = bool(cfg.get("unit_actions", False))
    algo_kwargs = {k: v for k, v in cfg.items() if k not in RUN_KEYS}
    if isinstance(algo_kwargs.get("policy_kwargs"), str):
        algo_kwargs["policy_kwargs"] = eval(algo_kwargs["policy_kwargs"], {"dict": dict})  # zoo style
    for key in ("learning_rate", "clip_range"):  # zoo style "lin_3e-4": linear decay to 0
        value = algo_kwargs.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            start = float(value[4:])
            algo_kwargs[key] = lambda progress_remaining, start=start: progress_remaining * start

    out = args.out or Path("runs") / f"{args.algo}_seed{args.seed}"
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    set_random_seed(args.seed)

    env = make_env(n_envs, args.seed, cfg["env_kwargs"], normalize, frame_stack, True, unit_actions)
    eval_env = make_env(4, args.seed + 10_000, cfg["env_kwargs"], normalize, frame_stack, False,
                        unit_actions)

    cls = getattr(sb3, args.algo.upper())
    model = cls(cfg.get("policy", "MlpPolicy"), env, seed=args.seed, device="cpu",
                verbose=args.verbose, tensorboard_log=str(out / "tb") if args.tensorboard else None,
                **algo_kwargs)
    callbacks = []
    if args.eval_freq > 0:
        callbacks.append(EvalCallback(eval_env, n_eval_episodes=args.eval_episodes,
                                      eval_freq=max(args.eval_freq // n_envs, 1),
                                      best_model_save_path=str(out), log_path=str(out),
                                      deterministic=True, verbose=args.verbose))
    if args.save_freq > 0:
        callbacks.append(CheckpointCallback(save_freq=max(args.save_freq // n_envs, 1),
                                            save_path=str(out / "checkpoints"), name_prefix="model",
                                            save_vecnormalize=normalize))

    started = time.time()
    model.learn(total_timesteps=n_timesteps, callback=callbacks, progress_bar=args.progress_bar,
                tb_log_name=args.algo)
    wall = time.time() - started

    model.save(str(out / "model.zip"))
    vecnorm = unwrap_vec_wrapper(env, VecNormalize) if normalize else None
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
           unit_actions)
    if args.ship is not None:
        shipped = export(model, args.ship, args.algo, cfg["env_kwargs"], frame_stack, vecnorm,
                         trained, unit_actions)
        print(f"shipped {shipped} (+ .json)")
    print(json.dumps({"out": str(out), "wall_time_s": round(wall, 1), "n_timesteps": n_timesteps}))
    shutil.rmtree(out / "tmp", ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
