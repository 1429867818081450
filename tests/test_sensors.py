"""The sensor chain written once (neck_env.sensors): the kernels the env core uses, their
batched forms (the diagnosis and the synthetic rig use them too), checked against what they
must read."""

import numpy as np
import pytest

from neck_env import effects as fx
from neck_env.sensors import accel_tilt_batch, imu_tilt_series


def _poses(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    q = np.stack([0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.4 * t), 0.02 * np.sin(t)], axis=1)
    return np.ascontiguousarray(q + 1e-3 * rng.normal(size=q.shape))


def test_accel_tilt_batch_reads_the_bend_of_an_untwisted_neck():
    # constant curvature, no twist, level mount: the head plate is tilted by the bend angle
    # itself, in the bend's direction, so the settled reading is the bend vector in degrees
    q = _poses()
    q[:, 2] = 0.0
    out = np.empty((len(q), 2))
    accel_tilt_batch(q, np.eye(3), out)
    np.testing.assert_allclose(out, np.degrees(q[:, :2]), atol=1e-9)
    # a twist or a yawed mount turns the reading's direction, never its size
    twisted, yawed = np.empty_like(out), np.empty_like(out)
    qt = q.copy()
    qt[:, 2] = 0.3
    accel_tilt_batch(np.ascontiguousarray(qt), np.eye(3), twisted)
    accel_tilt_batch(q, np.ascontiguousarray(fx.imu_mount(
        {"imu_misalignment": {"yaw_deg": 25.0, "tilt_deg": 0.0, "tilt_dir_deg": 0.0}})), yawed)
    for got in (twisted, yawed):
        np.testing.assert_allclose(np.hypot(*got.T), np.hypot(*out.T), atol=1e-9)
        assert np.abs(got - out).max() > 1.0


def test_thermistor_lag_is_a_first_order_lag():
    from neck_env.sensors import thermistor_lag_series

    # a ramp of slope a through a first-order lag settles a * tau behind it
    t = np.concatenate([np.arange(0, 10, 0.1), 10 + np.arange(1, 200) * 0.037])  # uneven
    x = np.stack([20 + 3.0 * t, np.full_like(t, 25.0)], axis=1)
    out = np.empty_like(x)
    thermistor_lag_series(x, t, 0.8, out)
    assert out[0, 0] == x[0, 0]
    np.testing.assert_allclose(x[-1, 0] - out[-1, 0], 3.0 * 0.8, rtol=1e-6)
    np.testing.assert_allclose(out[:, 1], 25.0)
    # after a jump the reading closes the gap as exp(-t / tau), exactly at every uneven sample
    step = np.full((len(t), 1), 10.0)
    step[0] = 0.0
    lag = np.empty_like(step)
    thermistor_lag_series(step, t, 0.8, lag)
    assert 0.0 < lag[1, 0] < 10.0
    np.testing.assert_allclose(lag[1:, 0], 10.0 + (lag[1, 0] - 10.0) * np.exp(-(t[1:] - t[1]) / 0.8),
                               rtol=1e-9)
    # zero lag passes the input through
    thermistor_lag_series(x, t, 0.0, out)
    np.testing.assert_array_equal(out, x)


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
