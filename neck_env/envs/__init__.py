"""Gymnasium environments: NeckTrack-v0, single and natively batched."""

from .core import Randomization, TaskConfig
from .neck_track import NeckTrackEnv, NeckTrackVectorEnv

__all__ = ["NeckTrackEnv", "NeckTrackVectorEnv", "Randomization", "TaskConfig"]
