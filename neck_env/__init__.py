"""neck_env: simulator, Gymnasium environment and sim-to-real tools for an SMA-actuated continuum neck.

``import neck_env`` registers ``NeckTrack-v0`` and ``NeckTrack-v1`` with Gymnasium (single env
through ``gymnasium.make``, natively batched through ``gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")``). v1 is v0 with a budget that binds and the rig's
firmware actuation (``V1_KWARGS``; the env docstring's "Version History").
"""

from gymnasium.envs.registration import register, registry

from .params import NeckParams, default_params

__all__ = ["NeckParams", "default_params", "V1_KWARGS"]
__version__ = "0.1.0"

#: What NeckTrack-v1 sets on top of v0's defaults (its keyword arguments can still override them).
#: 900 J: the largest budget on a 100 J grid at which the PID's RMSE is >= 15 % worse than with
#: no budget (30 episodes, seeds 1000-1029, firmware actuation: 6.67 deg unlimited, 7.48 at
#: 1000 J (+12 %), 8.37 at 900 J (+26 %)).
V1_KWARGS = {"energy_budget_J": 900.0, "actuation": "firmware"}

if "NeckTrack-v0" not in registry:
    register(
        id="NeckTrack-v0",
        entry_point="neck_env.envs.neck_track:NeckTrackEnv",
        vector_entry_point="neck_env.envs.neck_track:NeckTrackVectorEnv",
    )

if "NeckTrack-v1" not in registry:
    register(
        id="NeckTrack-v1",
        entry_point="neck_env.envs.neck_track:NeckTrackEnv",
        vector_entry_point="neck_env.envs.neck_track:NeckTrackVectorEnv",
        kwargs=dict(V1_KWARGS),
    )
