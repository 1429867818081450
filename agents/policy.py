"""A trained policy packaged for use outside training: the benchmark, the rig, your code.

A deployable policy is two files side by side:

* ``NAME.zip`` -- the SB3 model (``model.save``), or for ``algo: "ARS"`` (``agents.ars``) the
  weights as an npz archive: a linear residual on a controller (``"residual"`` in the JSON) or
  the muscle-shared law (``"muscle"``, ``agents.muscle_policy``),
* ``NAME.json`` -- ``{"algo", "env_id", "env_kwargs", "frame_stack", "unit_actions",
  "obs_norm": {"mean", "var", "clip", "epsilon"} | null, "trained": {...provenance...}}``.

The observation normalization and frame stacking the model was trained with are stored in the
JSON (no pickles), and ``DeployedPolicy.act`` applies them, so a caller feeds raw observations
of ``NeckTrack-v0`` (or of the rig env, which builds the same observation).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

ALGOS = ("PPO", "SAC", "A2C", "TD3")


def _algo_class(name: str):
    import stable_baselines3 as sb3

    if name.upper() not in ALGOS:
        raise ValueError(f"unknown algorithm {name!r}; known: {ALGOS}")
    return getattr(sb3, name.upper())


class DeployedPolicy:
    """Raw observation in, action out, for one env (call ``reset`` at each episode start)."""

    def __init__(self, model, meta: dict[str, Any], env_kwargs: dict[str, Any] | None = None):
        """``env_kwargs``: the task the policy runs in (a residual policy's PID models it:
        budget, actuation); default the task it was trained in."""
        self.model = model
        self.meta = meta
        self.residual = None
        self.muscle = None
        task_kwargs = dict(meta.get("env_kwargs", {})) if env_kwargs is None else dict(env_kwargs)
        if meta.get("muscle") is not None:  # the muscle-shared law: its own features and memory
            from agents.muscle_policy import MusclePolicy

            self.muscle = MusclePolicy(task_kwargs, 1, model.w)
        if meta.get("residual") is not None:
            from agents.residual import ControllerResidual

            self.residual = ControllerResidual(task_kwargs, 1, float(meta["residual"]["scale_A"]),
                                               meta["residual"].get("base", "pid"))
        self.frame_stack = int(meta.get("frame_stack", 1))
        norm = meta.get("obs_norm")
        if norm is not None:
            self._mean = np.asarray(norm["mean"], dtype=np.float64)
            self._std = np.sqrt(np.asarray(norm["var"], dtype=np.float64) + float(norm["epsilon"]))
            self._clip = float(norm["clip"])
        else:
            self._mean = None
        self._stack: np.ndarray | None = None

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return dict(self.meta.get("env_kwargs", {}))

    @classmethod
    def load(cls, path: str | Path, env_kwargs: dict[str, Any] | None = None) -> "DeployedPolicy":
        path = Path(path)
        zip_path = path if path.suffix == ".zip" else path.with_suffix(".zip")
        meta_path = zip_path.with_suffix(".json")
        for p in (zip_path, meta_path):
            if not p.exists():
                raise FileNotFoundError(f"deployable policy needs {p} (zip + json side by side)")
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{meta_path}: not valid JSON ({exc})") from exc
        if "algo" not in meta:
            raise ValueError(f"{meta_path}: missing key 'algo'")
        if str(meta["algo"]).upper() == "ARS" and "muscle" in meta:  # agents.muscle_policy
            from agents.muscle_policy import MuscleWeights

            model = MuscleWeights.load(zip_path)
        elif str(meta["algo"]).upper() == "ARS":  # a linear residual (agents.ars): numpy weights
            from agents.ars import LinearResidual

            model = LinearResidual.load(zip_path)
        else:
            model = _algo_class(meta["algo"]).load(str(zip_path), device="cpu")
        return cls(model, meta, env_kwargs)

    def _normalize(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float64)
        if self._mean is None:
            return obs.astype(np.float32)
        return np.clip((obs - self._mean) / self._std, -self._clip, self._clip).astype(np.float32)

    def reset(self) -> None:
        """Start an episode: the next ``act`` sees zeros for the frames before it (as SB3's
        frame stacking does after a reset)."""
        self._stack = None
        if self.residual is not None:
            self.residual.reset([0])
        if self.muscle is not None:
            self.muscle.reset()

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Action for the latest observation (first call after ``reset``: the reset observation)."""
        if self.muscle is not None:
            return self.muscle.act(np.asarray(obs)[None])[0]
        if self.residual is not None:
            feat = self.residual.features(np.asarray(obs)[None])[0]
            r, _ = self.model.predict(self._normalize(feat), deterministic=True)
            return self.residual.actions(r[None])[0]
        frame = self._normalize(obs)
        if self._stack is None:
            self._stack = np.zeros(frame.size * self.frame_stack, dtype=np.float32)
        else:
            self._stack = np.roll(self._stack, -frame.size)
        self._stack[-frame.size:] = frame
        action, _ = self.model.predict(self._stack, deterministic=True)
        if self.meta.get("unit_actions", False):
            from agents.sb3_env import unit_to_current

            return unit_to_current(action).astype(np.float32)
        return action


def export(model, path: str | Path, algo: str, env_kwargs: dict[str, Any], frame_stack: int,
           vecnormalize=None, trained: dict[str, Any] | None = None,
           unit_actions: bool = False, env_id: str = "NeckTrack-v0",
           residual: dict[str, Any] | None = None) -> Path:
    """Write ``path`` (.zip) and its .json so ``DeployedPolicy.load`` can use it."""
    zip_path = Path(path).with_suffix(".zip")
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(zip_path))
    norm = None
    if vecnormalize is not None and vecnormalize.norm_obs:
        rms = vecnormalize.obs_rms
        norm = {"mean": rms.mean.tolist(), "var": rms.var.tolist(),
                "clip": float(vecnormalize.clip_obs), "epsilon": float(vecnormalize.epsilon)}
    meta = {"algo": algo.upper(), "env_id": env_id, "env_kwargs": env_kwargs,
            "frame_stack": frame_stack, "unit_actions": unit_actions, "obs_norm": norm,
            "trained": trained or {}}
    if residual is not None:
        meta["residual"] = residual
    zip_path.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return zip_path
