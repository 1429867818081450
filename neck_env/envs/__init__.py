"""Gymnasium environments: NeckTrack-v0, single and natively batched (the task: ``neck_env.task``)."""

from ..task import Task
from .core import Randomization
from .neck_track import NeckTrackEnv, NeckTrackVectorEnv

__all__ = ["NeckTrackEnv", "NeckTrackVectorEnv", "Randomization", "Task"]
