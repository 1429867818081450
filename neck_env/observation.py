"""The observation both environments build: IMU tilt, spring temperatures, target, energy.

The simulated env and the hardware env (``neck_env.rig``) call the same functions here: the
tilt of an MPU6050 from its accelerometer, the complementary filter that fuses the gyro, and
the flat observation vector. A policy therefore sees the same thing on the rig as in simulation.

Observation (``Box(float32, (8,))``):

| index | name               | unit | range        | meaning                                          |
|-------|--------------------|------|--------------|--------------------------------------------------|
| 0     | tilt_x_deg         | deg  | [-90, 90]    | measured tilt vector theta cos(phi)              |
| 1     | tilt_y_deg         | deg  | [-90, 90]    | measured tilt vector theta sin(phi)              |
| 2-4   | T1_C, T2_C, T3_C   | degC | [-40, 300]   | spring temperature of muscle 1-3 (180/60/300 deg)|
| 5     | target_x_deg       | deg  | [-90, 90]    | target tilt vector theta* cos(phi*)              |
| 6     | target_y_deg       | deg  | [-90, 90]    | target tilt vector theta* sin(phi*)              |
| 7     | energy_left_frac   | -    | [0, 1]       | remaining fraction of the episode energy budget |

The tilt is given as a vector rather than (theta, phi) because phi is undefined upright.
Values outside the ranges (a sensor fault, a spring above 300 C) are clipped to them.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from .physics.compile import jit

OBS_NAMES = ("tilt_x_deg", "tilt_y_deg", "T1_C", "T2_C", "T3_C", "target_x_deg", "target_y_deg",
             "energy_left_frac")
OBS_LOW = np.array([-90, -90, -40, -40, -40, -90, -90, 0], dtype=np.float32)
OBS_HIGH = np.array([90, 90, 300, 300, 300, 90, 90, 1], dtype=np.float32)
OBS_DIM = len(OBS_NAMES)
OBS_LOW_T = tuple(float(v) for v in OBS_LOW)  # tuples: compile-time constants for numba
OBS_HIGH_T = tuple(float(v) for v in OBS_HIGH)
FILTER_TAU_S = 0.5  # complementary filter: accelerometer weight over this time constant


def observation_space() -> spaces.Box:
    return spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32)


@jit
def tilt_from_accel(ax, ay, az):
    """Tilt vector (deg) of the IMU z axis from gravity as the accelerometer sees it (any unit).

    Upright the sensor reads (0, 0, +1 g); bent by theta toward phi it reads
    ``(-sin theta cos phi, -sin theta sin phi, cos theta)``.
    """
    horiz = math.sqrt(ax * ax + ay * ay)
    theta = math.degrees(math.atan2(horiz, az))
    if horiz == 0.0:
        return 0.0, 0.0
    return -theta * ax / horiz, -theta * ay / horiz


@jit
def fuse_tilt(bx, by, ax, ay, az, gx_dps, gy_dps, dt_s, tau_s):
    """One complementary-filter update of the tilt vector (deg).

    The gyro predicts the tilt change (for the tilts of this neck the tilt vector moves with the
    head-frame rates as ``(gy, -gx)``); the accelerometer tilt corrects it with weight
    ``dt / (tau + dt)``, which removes the gyro bias with time constant tau.
    """
    px = bx + gy_dps * dt_s
    py = by - gx_dps * dt_s
    mx, my = tilt_from_accel(ax, ay, az)
    w = dt_s / (tau_s + dt_s)
    return px + w * (mx - px), py + w * (my - py)


@jit
def fill_observation(obs, tilt_x, tilt_y, T1, T2, T3, target_x, target_y, energy_frac):
    obs[0] = tilt_x
    obs[1] = tilt_y
    obs[2] = T1
    obs[3] = T2
    obs[4] = T3
    obs[5] = target_x
    obs[6] = target_y
    obs[7] = energy_frac
    for i in range(8):  # keep inside the documented Box whatever the sensor did
        lo = OBS_LOW_T[i]
        hi = OBS_HIGH_T[i]
        obs[i] = lo if obs[i] < lo else (hi if obs[i] > hi else obs[i])



def tilt_angles_deg(tilt_x: np.ndarray | float, tilt_y: np.ndarray | float):
    """(theta, phi) in degrees from a tilt vector; phi in [0, 360)."""
    return np.hypot(tilt_x, tilt_y), np.mod(np.degrees(np.arctan2(tilt_y, tilt_x)), 360.0)
