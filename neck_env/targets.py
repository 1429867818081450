"""Target head poses for the tracking task: seeded waypoints reached by steps or ramps, held.

A target trajectory is a list of segments. Segment j starts at ``t0[j]``; over ``ramp[j]``
seconds the target moves in a straight line (in tilt-vector space) from the previous waypoint
to ``waypoint[j]`` (``ramp = 0`` is a step) and then holds there until the next segment. The
first segment starts from upright.

``TargetSpec`` sets the distribution; ``sample_targets`` draws one trajectory from a numpy
``Generator`` (so the same seed gives the same targets); ``target_at`` evaluates it in compiled
code (the environments call it every step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from .physics.compile import jit


@dataclass(frozen=True)
class TargetSpec:
    """Distribution of target trajectories (angles in degrees, times in seconds)."""

    # Reachable workspace under the 160 C over-temperature cut: 31 deg toward a muscle, ~21 deg
    # midway between two (two springs share the bend). The bound interpolates smoothly between
    # the two directions with some margin: theta_max(phi) = mid + (along - mid)(1 + cos 3(phi - 180)) / 2.
    theta_max_deg: float = 25.0  # toward a muscle (phi = 180, 60, 300 deg)
    theta_max_between_deg: float = 18.0  # midway between two muscles (phi = 0, 120, 240 deg)
    theta_min_deg: float = 5.0  # a non-upright waypoint tilts at least this much
    upright_probability: float = 0.2  # chance that a waypoint is upright (theta* = 0)
    hold_s: tuple[float, float] = (8.0, 20.0)  # segment duration (ramp + hold): SMA cools in ~20 s
    step_probability: float = 0.5  # chance that a segment is a step rather than a ramp
    ramp_s: tuple[float, float] = (2.0, 6.0)
    first_hold_s: float = 2.0  # the target stays upright for this long at the start

    def __post_init__(self) -> None:
        if not (0 < self.theta_min_deg <= min(self.theta_max_deg, self.theta_max_between_deg)
                and max(self.theta_max_deg, self.theta_max_between_deg) <= 60):
            raise ValueError("targets: need 0 < theta_min_deg <= theta_max_deg, "
                             "theta_max_between_deg <= 60, got "
                             f"{self.theta_min_deg}, {self.theta_max_deg}, {self.theta_max_between_deg}")
        for name in ("upright_probability", "step_probability"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise ValueError(f"targets.{name} = {v}: must lie in [0, 1]")
        for name in ("hold_s", "ramp_s"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"targets.{name} = {(lo, hi)}: need 0 < low <= high")
        if self.ramp_s[1] > self.hold_s[0]:
            raise ValueError("targets: ramp_s must not exceed the shortest hold_s")
        if self.first_hold_s < 0:
            raise ValueError("targets.first_hold_s must be >= 0")

    def theta_max_at(self, phi_rad: float) -> float:
        """Largest target tilt (deg) in direction phi (rad)."""
        w = 0.5 * (1.0 + math.cos(3.0 * (phi_rad - math.pi)))
        return self.theta_max_between_deg + (self.theta_max_deg - self.theta_max_between_deg) * w

    def max_segments(self, episode_s: float) -> int:
        return int(math.ceil(max(episode_s - self.first_hold_s, 0.0) / self.hold_s[0])) + 2


def sample_targets(spec: TargetSpec, episode_s: float, rng: np.random.Generator,
                   max_segments: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(t0 (M,), ramp (M,), waypoint (M, 2) tilt vectors in deg, number used)."""
    t0 = np.full(max_segments, np.inf)
    ramp = np.zeros(max_segments)
    way = np.zeros((max_segments, 2))
    t0[0] = 0.0  # upright hold first
    t, n = spec.first_hold_s, 1
    while t < episode_s and n < max_segments:
        upright = rng.random() < spec.upright_probability
        phi = rng.uniform(0.0, 2 * math.pi)
        theta = 0.0 if upright else rng.uniform(spec.theta_min_deg, spec.theta_max_at(phi))
        t0[n] = t
        ramp[n] = 0.0 if rng.random() < spec.step_probability else rng.uniform(*spec.ramp_s)
        way[n] = theta * math.cos(phi), theta * math.sin(phi)
        t += rng.uniform(*spec.hold_s)
        n += 1
    return t0, ramp, way, n


@jit
def target_at(t, t0, ramp, way, n):
    """Target tilt vector (deg) at time t for one trajectory."""
    j = 0
    while j + 1 < n and t0[j + 1] <= t:
        j += 1
    x, y = way[j, 0], way[j, 1]
    if j > 0 and ramp[j] > 0.0 and t - t0[j] < ramp[j]:
        a = (t - t0[j]) / ramp[j]
        px, py = way[j - 1, 0], way[j - 1, 1]
        return px + a * (x - px), py + a * (y - py)
    return x, y


@jit
def tracking_error_deg(tilt_x, tilt_y, target_x, target_y):
    """Distance between the head's and the target's tilt vectors (deg).

    For tilts up to ~30 deg this is within 2 % of the angle between the actual and target head
    axes, and unlike a (theta, phi) error it is well defined upright.
    """
    dx = tilt_x - target_x
    dy = tilt_y - target_y
    return math.sqrt(dx * dx + dy * dy)
