"""neck_env: simulator, Gymnasium environment and sim-to-real tools for an SMA-actuated continuum neck."""

from .params import NeckParams, default_params

__all__ = ["NeckParams", "default_params"]
__version__ = "0.1.0"
