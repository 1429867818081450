"""neck_env: simulator, Gymnasium environment and sim-to-real tools for an SMA-actuated continuum neck.

``import neck_env`` registers ``NeckTrack-v0`` with Gymnasium (single env through
``gymnasium.make``, natively batched through ``gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")``).
"""

from gymnasium.envs.registration import register, registry

from .params import NeckParams, default_params

__all__ = ["NeckParams", "default_params"]
__version__ = "0.1.0"

if "NeckTrack-v0" not in registry:
    register(
        id="NeckTrack-v0",
        entry_point="neck_env.envs.neck_track:NeckTrackEnv",
        vector_entry_point="neck_env.envs.neck_track:NeckTrackVectorEnv",
    )
