"""The sensor chain written once (neck_env.sensors): the kernels the env core uses, their
batched forms, and that they agree with the copies the diagnosis still carries."""

import numpy as np
import pytest

from neck_env import effects as fx
from neck_env.sensors import accel_tilt_batch, imu_tilt_series


def _poses(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    q = np.stack([0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.4 * t), 0.02 * np.sin(t)], axis=1)
    return np.ascontiguousarray(q + 1e-3 * rng.normal(size=q.shape))


def test_series_is_the_synthetic_generators_sensor_pass():
    from neck_env.gap import synthetic

    q = _poses()
    rng = np.random.default_rng(1)
    mount = np.ascontiguousarray(fx.imu_mount(
        {"imu_misalignment": {"yaw_deg": 7.0, "tilt_deg": 2.0, "tilt_dir_deg": 40.0}}))
    ab, gb = rng.normal(0, 0.01, 3), rng.normal(0, 0.5, 3)
    an, gn = rng.normal(0, 0.004, (len(q), 3)), rng.normal(0, 0.05, (len(q), 2))
    got, want = np.empty((len(q), 2)), np.empty((len(q), 2))
    imu_tilt_series(q, 0.02, mount, ab, gb, 0.1, 0.01, an, gn, got)
    synthetic._sense(q, 0.02, mount, ab, gb, 0.1, 0.01, an, gn, want)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_accel_tilt_batch_is_the_diagnosis_models_imu_tilt():
    from neck_env.gap.model import imu_tilt

    q = _poses()
    mount = np.ascontiguousarray(fx.imu_mount(
        {"imu_misalignment": {"yaw_deg": -12.0, "tilt_deg": 3.0, "tilt_dir_deg": 200.0}}))
    out = np.empty((len(q), 2))
    accel_tilt_batch(q, mount, out)
    x, y = imu_tilt(q, mount)
    np.testing.assert_allclose(out[:, 0], x, atol=1e-9)
    np.testing.assert_allclose(out[:, 1], y, atol=1e-9)


def test_noise_free_series_follows_the_pose_and_removes_gyro_bias():
    q = _poses(1500)
    mount = np.eye(3)
    zero3, zeros = np.zeros(3), np.zeros((len(q), 3))
    series, settled = np.empty((len(q), 2)), np.empty((len(q), 2))
    imu_tilt_series(q, 0.02, mount, zero3, np.array([2.0, -2.0, 0.0]), 0.0, 0.0, zeros,
                    zeros[:, :2].copy(), series)
    accel_tilt_batch(q, mount, settled)
    # a constant gyro bias of 2 deg/s is removed by the filter (tau 0.5 s) to ~1 deg; the slow
    # pose is tracked
    assert np.abs(series[200:] - settled[200:]).max() < 1.5
    assert np.abs(settled[:, 0]).max() > 10.0
