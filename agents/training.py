"""The parts of a training run that ``train.py`` and ``agents.sweep`` share.

A config block (rl-baselines3-zoo style YAML, see ``agents/configs/``) holds run keys
(``RUN_KEYS``: how many rigs, how long, which wrappers) and the algorithm's constructor keywords;
``resolve_config`` splits them and turns zoo shorthands into Python objects, ``build_model``
makes the wrapped env and the SB3 model, ``vecnormalize_of`` finds the observation statistics
to ship with a policy.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

ALGOS = ("ppo", "sac", "a2c", "td3")
# Keys of a config block that configure the run, not the algorithm's constructor.
RUN_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "frame_stack", "unit_actions",
            "env_kwargs", "residual")
CONFIG_DIR = Path(__file__).resolve().parent / "configs"


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


@dataclass(frozen=True)
class RunSetup:
    """A config block split into the run's settings and the algorithm's keywords."""

    cfg: dict[str, Any]
    n_envs: int
    n_timesteps: int
    normalize: bool
    frame_stack: int
    unit_actions: bool
    algo_kwargs: dict[str, Any]
    # {"base": "pid", "scale_A": float}: residual RL on the PID (agents.residual), else None
    residual: dict[str, Any] | None = None

    @property
    def gamma(self) -> float:
        """The algorithm's discount (the config's ``gamma``, else SB3's default)."""
        return float(self.algo_kwargs.get("gamma", SB3_DEFAULT_GAMMA))


def resolve_config(cfg: dict[str, Any]) -> RunSetup:
    cfg = dict(cfg)
    cfg.setdefault("env_kwargs", {})
    algo_kwargs = {k: v for k, v in cfg.items() if k not in RUN_KEYS}
    if isinstance(algo_kwargs.get("policy_kwargs"), str):
        algo_kwargs["policy_kwargs"] = eval(algo_kwargs["policy_kwargs"], {"dict": dict})  # zoo style
    for key in ("learning_rate", "clip_range"):  # zoo style "lin_3e-4": linear decay to 0
        value = algo_kwargs.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            start = float(value[4:])
            algo_kwargs[key] = lambda progress_remaining, start=start: progress_remaining * start
    residual = cfg.get("residual")
    if residual is not None:
        residual = dict(residual)
        if residual.get("base", "pid") != "pid" or float(residual.get("scale_A", 0)) <= 0:
            raise ValueError(f"residual must be {{base: pid, scale_A: > 0}}, got {residual}")
        residual = {"base": "pid", "scale_A": float(residual["scale_A"]),
                    "squared_error": bool(residual.get("squared_error", False))}
        if cfg.get("frame_stack", 1) != 1 or cfg.get("unit_actions", False):
            raise ValueError("a residual policy takes no frame_stack / unit_actions (its features "
                             "carry the PID's state; its actions are the residual in [-1, 1])")
    return RunSetup(cfg, int(cfg["n_envs"]), int(float(cfg["n_timesteps"])),
                    bool(cfg.get("normalize", False)), int(cfg.get("frame_stack", 1)),
                    bool(cfg.get("unit_actions", False)), algo_kwargs, residual)


SB3_DEFAULT_GAMMA = 0.99  # every ALGOS class's default discount


def make_env(n_envs: int, seed: int, env_kwargs: dict[str, Any], normalize: bool,
             frame_stack: int, training: bool, unit_actions: bool,
             gamma: float = SB3_DEFAULT_GAMMA, residual: dict[str, Any] | None = None):
    """The wrapped batched env; ``gamma``: the algorithm's discount, which VecNormalize's
    reward scaling must use (its return estimate is discounted like the agent's);
    ``residual``: the residual-on-PID env (``agents.residual``) instead of the plain one."""
    from stable_baselines3.common.vec_env import VecFrameStack, VecMonitor, VecNormalize

    from agents.sb3_env import NeckTrackSB3VecEnv

    if residual is not None:
        from agents.residual import make_residual_vec_env

        # evaluation envs replay the same episodes at every evaluation, and report -e (deg)
        inner = make_residual_vec_env(n_envs, seed, residual["scale_A"], env_kwargs,
                                      reseed_every_reset=not training,
                                      squared_error=training and residual["squared_error"])
    else:
        inner = NeckTrackSB3VecEnv(n_envs, seed=seed, unit_actions=unit_actions, **env_kwargs)
    venv = VecMonitor(inner)
    if normalize:
        venv = VecNormalize(venv, training=training, norm_obs=True, norm_reward=training,
                            gamma=gamma)
    if frame_stack > 1:
        venv = VecFrameStack(venv, frame_stack)
    return venv


def build_model(algo: str, run: RunSetup, seed: int, tensorboard_dir: Path | None,
                verbose: int = 0):
    """The seeded training env and the SB3 model on it (CPU)."""
    import stable_baselines3 as sb3
    from stable_baselines3.common.utils import set_random_seed

    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; known: {ALGOS}")
    set_random_seed(seed)
    env = make_env(run.n_envs, seed, run.cfg["env_kwargs"], run.normalize, run.frame_stack, True,
                   run.unit_actions, run.gamma, run.residual)
    model = getattr(sb3, algo.upper())(
        run.cfg.get("policy", "MlpPolicy"), env, seed=seed, device="cpu", verbose=verbose,
        tensorboard_log=str(tensorboard_dir) if tensorboard_dir is not None else None,
        **run.algo_kwargs)
    if run.residual is not None:
        zero_mean_action(model)
    return model, env


def zero_mean_action(model) -> None:
    """Zero the layer that outputs the mean action: a residual policy then starts as the PID
    (its mean correction is 0; exploration noise stays)."""
    import torch

    net = getattr(model.policy, "action_net", None)
    if net is None:  # off-policy actors (SAC, TD3): the last linear layer of the actor's mu
        net = [m for m in model.policy.actor.mu.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        net.weight.zero_()
        net.bias.zero_()


def vecnormalize_of(env, run: RunSetup):
    """The VecNormalize inside the training env (its statistics ship with the policy), or None."""
    from stable_baselines3.common.vec_env import VecNormalize, unwrap_vec_wrapper

    return unwrap_vec_wrapper(env, VecNormalize) if run.normalize else None


def rollout_steps(model) -> int:
    """Env steps per rollout SB3 collects: ``n_steps x n_envs`` for PPO/A2C, ``train_freq x
    n_envs`` for SAC/TD3. ``model.learn(T)`` runs whole rollouts, so it takes T rounded up to a
    multiple of this."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    if isinstance(model, OnPolicyAlgorithm):
        return model.n_steps * model.n_envs
    tf = model.train_freq
    return model.n_envs * (tf.frequency if tf.unit.value == "step" else 1)


def sync_normalization(train_env, eval_env) -> None:
    """Give the evaluation env the training env's observation statistics (as SB3's
    EvalCallback does before each evaluation)."""
    from stable_baselines3.common.vec_env import sync_envs_normalization

    sync_envs_normalization(train_env, eval_env)
