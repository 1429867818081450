"""Simulated sensors of the rig: the MPU6050 on the head and the spring thermistors.

The IMU reads specific force and body rates in its own frame, which is the head frame rotated
by the mount (``effects.imu_mount``). Each reading gets a per-episode bias and white noise; the
host then runs the same tilt pipeline as on the rig (``observation.fuse_tilt``).

Noise comes from a per-environment splitmix64 stream in compiled code, seeded from the env's
``np.random.Generator`` at reset: cheap at N = 4096 and identical for a single env and the
same env inside a vector env.

The sensor chain, written once (compiled; callers bring their own noise so each keeps its own
random stream):

* ``imu_measurement`` -- one MPU6050 sample: noise-free reading (``imu_reading``) + per-episode
  bias + gyro drift + white noise;
* ``imu_tilt_update`` -- the rig's tilt pipeline on that sample (``observation.fuse_tilt``;
  the first sample of an episode initializes from the accelerometer alone);
* ``imu_tilt_series`` -- both over a time series of poses of one rig (the batched form for
  recorded-rate data, e.g. synthetic datasets);
* ``accel_tilt_batch`` -- the noise-free accelerometer tilt of many poses (the filter's
  settled value, e.g. for a model fitted to recorded tilt);
* ``thermistor_lag_series`` -- what a lagging thermistor reads of a spring's temperature.

The env core calls the first two per rig and step inside its compiled pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from .physics.compile import jit

from .observation import FILTER_TAU_S, fuse_tilt, tilt_from_accel
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


@jit
def imu_scratch():
    """Scratch arrays of one ``imu_measurement`` call (kinematics and rotations, the noise-free
    reading (6,)); allocate once per loop."""
    return (np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3),
            np.empty(6))


@jit
def imu_measurement(q, q_prev, dt_s, mount, accel_bias_g, gyro_bias_dps, gyro_drift_dps,
                    accel_noise_g, gyro_noise_dps, scratch, out):
    """One MPU6050 sample for pose ``q`` (3,) after a step of ``dt_s`` from ``q_prev``.

    ``mount`` (3, 3): IMU axes in the head frame; ``accel_bias_g`` (3,), ``gyro_bias_dps`` (3,):
    per-episode biases; ``gyro_drift_dps``: the drifting part of the gyro bias now (added to
    x and y); ``accel_noise_g`` (3,), ``gyro_noise_dps`` (2,): this sample's white noise, already
    scaled. Fills ``out`` (5,): accelerometer x, y, z (g), gyro x, y (deg/s) -- what the tilt
    pipeline uses.
    """
    tip, dtip, rot, v, w, r = scratch
    imu_reading(q, q_prev, dt_s, mount, tip, dtip, rot, v, w, r)
    out[0] = r[0] + accel_bias_g[0] + accel_noise_g[0]
    out[1] = r[1] + accel_bias_g[1] + accel_noise_g[1]
    out[2] = r[2] + accel_bias_g[2] + accel_noise_g[2]
    out[3] = r[3] + gyro_bias_dps[0] + gyro_drift_dps + gyro_noise_dps[0]
    out[4] = r[4] + gyro_bias_dps[1] + gyro_drift_dps + gyro_noise_dps[1]


@jit
def imu_tilt_update(tilt_x_deg, tilt_y_deg, meas, dt_s, first):
    """The rig's tilt pipeline on one ``imu_measurement`` sample: the new tilt vector (deg).
    ``first``: the episode's first sample, taken from the accelerometer alone."""
    if first:
        return tilt_from_accel(meas[0], meas[1], meas[2])
    return fuse_tilt(tilt_x_deg, tilt_y_deg, meas[0], meas[1], meas[2], meas[3], meas[4], dt_s,
                     FILTER_TAU_S)


@jit
def imu_tilt_series(q, dt_s, mount, accel_bias_g, gyro_bias_dps, gyro_drift0_dps,
                    gyro_drift_rate_dps_per_s, accel_noise_g, gyro_noise_dps, out):
    """Measured tilt vectors of one rig over a pose series: ``q`` (S, 3) sampled every
    ``dt_s``; the gyro drift is ``gyro_drift0_dps + gyro_drift_rate_dps_per_s * k * dt_s`` at
    sample k; ``accel_noise_g`` (S, 3) and ``gyro_noise_dps`` (S, 2) are pre-drawn white noise
    (zeros for none). The first sample's previous pose is itself. Fills ``out`` (S, 2), deg."""
    scratch = imu_scratch()
    meas = np.empty(5)
    tx = 0.0
    ty = 0.0
    for k in range(q.shape[0]):
        prev = q[k - 1] if k > 0 else q[0]
        drift = gyro_drift0_dps + gyro_drift_rate_dps_per_s * k * dt_s
        imu_measurement(q[k], prev, dt_s, mount, accel_bias_g, gyro_bias_dps, drift,
                        accel_noise_g[k], gyro_noise_dps[k], scratch, meas)
        tx, ty = imu_tilt_update(tx, ty, meas, dt_s, k == 0)
        out[k, 0] = tx
        out[k, 1] = ty


@jit
def accel_tilt_batch(q, mount, out):
    """Noise-free accelerometer tilt vectors (deg) of an IMU with rotation ``mount`` (3, 3) in
    the head frame, for poses ``q`` (M, 3): ``imu_reading`` + ``tilt_from_accel`` at rest
    (what the filter settles to). Fills ``out`` (M, 2)."""
    tip, dtip, rot, v, w, r = imu_scratch()
    for k in range(q.shape[0]):
        imu_reading(q[k], q[k], 1.0, mount, tip, dtip, rot, v, w, r)
        out[k, 0], out[k, 1] = tilt_from_accel(r[0], r[1], r[2])


@jit
def thermistor_lag_series(x, t_s, tau_s, out):
    """What a thermistor with time constant ``tau_s`` reads of temperatures ``x`` (G, N) at
    sample times ``t_s`` (G,): a first-order lag, exact for ``x`` linear between samples (so
    uneven sample spacing is fine), starting settled (``out[0] = x[0]``). Fills ``out``.

    A bead glued to a spring lags it by ~0.5-2 s: while the spring heats at 10-20 C/s the
    reading trails by tens of degrees, which a model without the lag can only match by
    distorting the heat balance."""
    n = x.shape[1]
    for j in range(n):
        out[0, j] = x[0, j]
    for k in range(1, x.shape[0]):
        dt = t_s[k] - t_s[k - 1]
        if tau_s <= 0.0 or dt <= 0.0:
            for j in range(n):
                out[k, j] = x[k, j]
            continue
        e = math.exp(-dt / tau_s)
        for j in range(n):
            slope_tau = tau_s * (x[k, j] - x[k - 1, j]) / dt
            out[k, j] = x[k, j] - slope_tau + (out[k - 1, j] - x[k - 1, j] + slope_tau) * e
