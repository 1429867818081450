"""Simulated sensors of the rig: the MPU6050 on the head and the spring thermistors.

The IMU reads specific force and body rates in its own frame, which is the head frame rotated
by the mount (``effects.imu_mount``). Each reading gets a per-episode bias and white noise; the
host then runs the same tilt pipeline as on the rig (``observation.fuse_tilt``).

Noise comes from a per-environment splitmix64 stream in compiled code, seeded from the env's
``np.random.Generator`` at reset: cheap at N = 4096 and identical for a single env and the
same env inside a vector env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from .physics.compile import jit

from .physics.backbone import kinematics, rotate_bend


@dataclass(frozen=True)
class SensorParams:
    """Sensor model of the rig (MPU6050 at +-2 g / +-250 deg/s; NTC thermistors)."""

    # White noise per reading. MPU6050: 400 ug/sqrt(Hz) and 0.005 deg/s/sqrt(Hz) over a
    # ~44 Hz DLPF bandwidth give ~3 mg and ~0.03 deg/s; we round up for mount vibration.
    accel_noise_g: float = 0.004
    gyro_noise_dps: float = 0.05
    # Per-episode biases left after the usual start-up calibration (uncalibrated parts are
    # +-50 mg and +-20 deg/s).
    accel_bias_g: float = 0.008
    gyro_bias_dps: float = 0.5
    temperature_noise_C: float = 0.5

    def __post_init__(self) -> None:
        for name in ("accel_noise_g", "gyro_noise_dps", "accel_bias_g", "gyro_bias_dps",
                     "temperature_noise_C"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"sensors.{name} = {v!r}: must be a finite number >= 0")


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@jit
def next_uniform(rng, i):
    """Uniform in (0, 1] from the splitmix64 stream ``rng[i]`` (advanced in place)."""
    z = rng[i] + _GOLDEN
    rng[i] = z
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    z = z ^ (z >> _S31)
    return ((z >> _S11) + np.uint64(1)) * (1.0 / 9007199254740992.0)


_U16 = np.uint64(0xFFFF)
_S16, _S32, _S48 = np.uint64(16), np.uint64(32), np.uint64(48)


@jit
def next_normal(rng, i):
    """Approximately standard normal: the sum of four 16-bit uniforms of one draw (Irwin-Hall),
    centred and scaled to unit variance; bounded at +-3.46. Five times cheaper than Box-Muller,
    which matters at 4096 envs x 8 sensor channels per step."""
    z = rng[i] + _GOLDEN
    rng[i] = z
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    z = z ^ (z >> _S31)
    total = float((z & _U16) + ((z >> _S16) & _U16) + ((z >> _S32) & _U16) + (z >> _S48))
    # Sum of four U{0..65535}: mean 131070, variance 4 * (65536^2 - 1) / 12.
    return (total - 131070.0) * (1.0 / 37837.23)


@jit
def imu_reading(q, q_prev, dt_s, mount, scratch_tip, scratch_dtip, scratch_rot, v, w, out):
    """Noise-free IMU reading for pose q after a step from q_prev.

    ``mount`` (3, 3) rotates IMU axes into the head frame. Fills ``out`` with accelerometer
    (g, specific force in the IMU frame) and gyro (deg/s, IMU frame): out[0:3], out[3:6].
    """
    bx, by, eps = q[0], q[1], q[2]
    f1, f2 = kinematics(bx, by, 1.0, scratch_tip, scratch_dtip, scratch_rot)
    ce, se = math.cos(eps), math.sin(eps)
    # IMU axis j in the world: R_b R_z(eps) mount[:, j]; read gravity (+1 g up) and rates.
    wx = wy = wz = 0.0
    for i in range(3):
        rate = (q[i] - q_prev[i]) / dt_s
        wx += scratch_rot[i, 0] * rate
        wy += scratch_rot[i, 1] * rate
        wz += scratch_rot[i, 2] * rate
    for j in range(3):
        m0, m1, m2 = mount[0, j], mount[1, j], mount[2, j]
        v[0] = ce * m0 - se * m1
        v[1] = se * m0 + ce * m1
        v[2] = m2
        rotate_bend(bx, by, f1, f2, v, w)
        out[j] = w[2]
        out[3 + j] = math.degrees(wx * w[0] + wy * w[1] + wz * w[2])
