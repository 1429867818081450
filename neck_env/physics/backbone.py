"""Constant-curvature backbone kinematics (paper eq. 6-7, 15), singularity-free at theta = 0.

The pose is ``q = (b_x, b_y, eps)`` with the *bending vector* ``b = theta (cos phi, sin phi)``
(theta = kappa l, phi the bending-plane angle) and the twist eps. Unlike (kappa, phi), b is
smooth through the upright pose where phi is undefined.

With ``omega = (-b_y, b_x, 0)``, the head orientation of eq. 7,
``R_z(phi) R_y(theta) R_z(eps - phi)``, equals ``Rot(omega) R_z(eps)``: a rotation by theta about
the in-plane axis normal to the bending plane, then the twist. The tip position of eq. 6 is
``p(l) = l (f1 b_x, f1 b_y, f2)`` with ``f1 = (1 - cos theta) / theta^2`` and
``f2 = sin theta / theta``; every theta-function switches to its Taylor series near 0.

The compiled scalar functions serve the plant; the ``*_batch`` wrappers take ``q`` of shape
``(N, 3)`` for tests, rendering and sensors.
"""

from __future__ import annotations

import math

import numpy as np
from .compile import jit

_SERIES_BELOW = 1e-2  # rad; series truncation error < theta^6 / 5040 there


@jit
def theta_functions(theta):
    """(f1, f2, g1, g2, c2): (1-cos)/t^2, sin/t, f1'/t, f2'/t, (t-sin)/t^3."""
    if theta < _SERIES_BELOW:
        u = theta * theta
        return (0.5 - u / 24 + u * u / 720, 1 - u / 6 + u * u / 120,
                -1 / 12 + u / 180 - u * u / 6720, -1 / 3 + u / 30 - u * u / 840,
                1 / 6 - u / 120 + u * u / 5040)
    s, c = math.sin(theta), math.cos(theta)
    t2 = theta * theta
    t3 = t2 * theta
    return (1 - c) / t2, s / theta, s / t3 - 2 * (1 - c) / (t2 * t2), c / t2 - s / t3, (theta - s) / t3


@jit
def kinematics(bx, by, length, tip, dtip, rot):
    """Fill tip p(l) (3,), dtip[i] = dp/dq_i (3, 3) and rot[i] = world angular velocity per
    unit q_i_dot (3, 3). Returns (f1, f2) for ``rotate_bend``."""
    theta = math.sqrt(bx * bx + by * by)
    f1, f2, g1, g2, c2 = theta_functions(theta)
    l = length
    tip[0] = l * f1 * bx
    tip[1] = l * f1 * by
    tip[2] = l * f2
    dtip[0, 0] = l * (f1 + g1 * bx * bx)
    dtip[0, 1] = l * g1 * bx * by
    dtip[0, 2] = l * g2 * bx
    dtip[1, 0] = l * g1 * bx * by
    dtip[1, 1] = l * (f1 + g1 * by * by)
    dtip[1, 2] = l * g2 * by
    dtip[2, 0] = 0.0
    dtip[2, 1] = 0.0
    dtip[2, 2] = 0.0
    # Left Jacobian of the rotation vector omega (rows 0, 1) and R_b z for the twist (row 2).
    rot[0, 0] = -c2 * bx * by
    rot[0, 1] = 1 - c2 * by * by
    rot[0, 2] = -f1 * by
    rot[1, 0] = -1 + c2 * bx * bx
    rot[1, 1] = c2 * bx * by
    rot[1, 2] = f1 * bx
    rot[2, 0] = f2 * bx
    rot[2, 1] = f2 * by
    rot[2, 2] = 1 - f1 * theta * theta
    return f1, f2


@jit
def rotate_bend(bx, by, f1, f2, v, out):
    """out = Rot(omega) v (Rodrigues, omega = (-b_y, b_x, 0))."""
    wx, wy = -by, bx
    # w x v and w x (w x v) with w_z = 0
    a0 = wy * v[2]
    a1 = -wx * v[2]
    a2 = wx * v[1] - wy * v[0]
    out[0] = v[0] + f2 * a0 + f1 * (wy * a2)
    out[1] = v[1] + f2 * a1 + f1 * (-wx * a2)
    out[2] = v[2] + f2 * a2 + f1 * (wx * a1 - wy * a0)


def bend_angles(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) in radians from q (..., 3); phi in [0, 2 pi), 0 where theta == 0."""
    theta = np.hypot(q[..., 0], q[..., 1])
    phi = np.mod(np.arctan2(q[..., 1], q[..., 0]), 2 * np.pi)
    return theta, phi


def pose_from_angles(theta, phi, eps=0.0) -> np.ndarray:
    """q (..., 3) from (theta, phi, eps) in radians."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    eps = np.broadcast_to(np.asarray(eps, float), theta.shape)
    return np.stack([theta * np.cos(phi), theta * np.sin(phi), eps], axis=-1)


@jit
def _kinematics_rows(q, length, tip, dtip, rot):
    for n in range(q.shape[0]):
        kinematics(q[n, 0], q[n, 1], length, tip[n], dtip[n], rot[n])


def kinematics_batch(q: np.ndarray, length_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tip positions (N, 3), dtip/dq (N, 3, 3) and angular Jacobians (N, 3, 3) for poses q."""
    q = np.ascontiguousarray(q, dtype=float).reshape(-1, 3)
    n = q.shape[0]
    tip, dtip, rot = np.empty((n, 3)), np.empty((n, 3, 3)), np.empty((n, 3, 3))
    _kinematics_rows(q, float(length_m), tip, dtip, rot)
    return tip, dtip, rot


@jit
def _head_rotation_rows(q, out):
    tip, dtip, rot = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
    col = np.empty(3)
    for n in range(q.shape[0]):
        bx, by, eps = q[n, 0], q[n, 1], q[n, 2]
        f1, f2 = kinematics(bx, by, 1.0, tip, dtip, rot)
        ce, se = math.cos(eps), math.sin(eps)
        for j in range(3):  # columns of R_b R_z(eps)
            v = np.array([ce, se, 0.0]) if j == 0 else (np.array([-se, ce, 0.0]) if j == 1
                                                        else np.array([0.0, 0.0, 1.0]))
            rotate_bend(bx, by, f1, f2, v, col)
            out[n, :, j] = col


def head_rotation(q: np.ndarray) -> np.ndarray:
    """Head orientation matrices (N, 3, 3) of eq. 7: R_z(phi) R_y(theta) R_z(eps - phi)."""
    q = np.ascontiguousarray(q, dtype=float).reshape(-1, 3)
    out = np.empty((q.shape[0], 3, 3))
    _head_rotation_rows(q, out)
    return out


def backbone_points(q: np.ndarray, length_m: float, n_points: int = 20) -> np.ndarray:
    """Points p(s) along the arc (eq. 6), s in [0, l], shape (N, n_points, 3). For drawing."""
    q = np.asarray(q, float).reshape(-1, 3)
    fracs = np.linspace(0.0, 1.0, n_points)
    # Arc length s = frac * l has bending vector frac * b.
    qs = (q[:, None, :] * np.array([1.0, 1.0, 0.0]) * fracs[None, :, None]).reshape(-1, 3)
    pts = np.empty((qs.shape[0], 3))
    for i, frac in enumerate(np.tile(fracs, q.shape[0])):
        tip, _, _ = kinematics_batch(qs[i:i + 1], length_m * frac)
        pts[i] = tip[0]
    return pts.reshape(q.shape[0], n_points, 3)
