"""Constant-curvature backbone kinematics (paper eq. 6-7, 15), singularity-free at theta = 0.

The pose is held as ``q = (b_x, b_y, eps)`` with the *bending vector*
``b = theta * (cos phi, sin phi)`` (theta = kappa * l, phi the bending-plane angle) and the twist
``eps``. Unlike (kappa, phi), b is smooth through the upright pose where phi is undefined.

With ``omega = (-b_y, b_x, 0)`` the head orientation of eq. 7,
``R_z(phi) R_y(theta) R_z(eps - phi)``, equals ``Rot(omega) R_z(eps)`` (a rotation by theta
about the in-plane axis perpendicular to the bending plane, then the twist), and the tip
position of eq. 6 is ``p(l) = l * (f1 b_x, f1 b_y, f2)`` with ``f1 = (1 - cos theta) / theta^2``
and ``f2 = sin theta / theta``. All theta-functions switch to their Taylor series near 0.

Shapes: ``q`` is ``(N, 3)``; vectors returned are ``(N, 3)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

_SERIES_BELOW = 1e-2  # rad; series truncation error < theta^6 / 5040 there


class ThetaFunctions(NamedTuple):
    """Smooth functions of theta (each (N,))."""

    f1: np.ndarray  # (1 - cos t) / t^2
    f2: np.ndarray  # sin t / t
    g1: np.ndarray  # f1'(t) / t
    g2: np.ndarray  # f2'(t) / t
    c2: np.ndarray  # (t - sin t) / t^3


def theta_functions(theta: np.ndarray) -> ThetaFunctions:
    t = np.maximum(theta, _SERIES_BELOW)
    s, c = np.sin(t), np.cos(t)
    t2 = t * t
    f1 = (1 - c) / t2
    f2 = s / t
    g1 = s / (t2 * t) - 2 * (1 - c) / (t2 * t2)
    g2 = c / t2 - s / (t2 * t)
    c2 = (t - s) / (t2 * t)
    small = theta < _SERIES_BELOW
    if np.any(small):
        u = theta * theta
        f1 = np.where(small, 0.5 - u / 24 + u * u / 720, f1)
        f2 = np.where(small, 1 - u / 6 + u * u / 120, f2)
        g1 = np.where(small, -1 / 12 + u / 180 - u * u / 6720, g1)
        g2 = np.where(small, -1 / 3 + u / 30 - u * u / 840, g2)
        c2 = np.where(small, 1 / 6 - u / 120 + u * u / 5040, c2)
    return ThetaFunctions(f1, f2, g1, g2, c2)


def bend_angles(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) in radians from q; phi in [0, 2 pi), 0 where theta == 0."""
    theta = np.hypot(q[..., 0], q[..., 1])
    phi = np.mod(np.arctan2(q[..., 1], q[..., 0]), 2 * np.pi)
    return theta, phi


def pose_from_angles(theta: np.ndarray, phi: np.ndarray, eps: np.ndarray | float = 0.0) -> np.ndarray:
    """q from (theta, phi, eps) in radians."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    eps = np.broadcast_to(np.asarray(eps, float), theta.shape)
    return np.stack([theta * np.cos(phi), theta * np.sin(phi), eps], axis=-1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([
        a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
        a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
    ], axis=-1)


class BackboneKinematics(NamedTuple):
    """Tip pose and its derivatives for the virtual-work generalized forces."""

    tip_m: np.ndarray  # p(l), (N, 3)
    omega: np.ndarray  # rotation vector of the bend, (N, 3)
    tf: ThetaFunctions
    dtip_dq: np.ndarray  # (N, 3 [q], 3 [xyz]); d/d eps is zero
    rot_axis_dq: np.ndarray  # (N, 3 [q], 3 [xyz]): world angular velocity per unit q_dot


def kinematics(q: np.ndarray, length_m: np.ndarray) -> BackboneKinematics:
    """Tip position p(l) (eq. 6), orientation and their Jacobians w.r.t. q.

    ``length_m`` broadcasts against ``(N,)`` (shape (B,) or scalar).
    """
    bx, by = q[:, 0], q[:, 1]
    theta = np.hypot(bx, by)
    tf = theta_functions(theta)
    l = length_m
    zero = np.zeros_like(bx)
    tip = np.stack([l * tf.f1 * bx, l * tf.f1 * by, l * tf.f2 * np.ones_like(bx)], axis=-1)
    omega = np.stack([-by, bx, zero], axis=-1)
    dtip = np.stack([
        np.stack([l * (tf.f1 + tf.g1 * bx * bx), l * tf.g1 * bx * by, l * tf.g2 * bx], -1),
        np.stack([l * tf.g1 * bx * by, l * (tf.f1 + tf.g1 * by * by), l * tf.g2 * by], -1),
        np.stack([zero, zero, zero], -1),
    ], axis=1)
    # Left Jacobian of the rotation vector: Omega = J_l(omega) omega_dot (+ R_b z eps_dot).
    rot = np.stack([
        np.stack([-tf.c2 * bx * by, 1 - tf.c2 * by * by, -tf.f1 * by], -1),
        np.stack([-1 + tf.c2 * bx * bx, tf.c2 * bx * by, tf.f1 * bx], -1),
        np.stack([tf.f2 * bx, tf.f2 * by, 1 - tf.f1 * theta * theta], -1),
    ], axis=1)
    return BackboneKinematics(tip, omega, tf, dtip, rot)


def rotate_bend(kin: BackboneKinematics, v: np.ndarray) -> np.ndarray:
    """Apply the bend rotation Rot(omega) (Rodrigues) to vectors v of shape (N, ..., 3)."""
    extra = v.ndim - 2
    w = kin.omega.reshape(kin.omega.shape[:1] + (1,) * extra + (3,))
    f1 = kin.tf.f1.reshape((-1,) + (1,) * extra + (1,))
    f2 = kin.tf.f2.reshape((-1,) + (1,) * extra + (1,))
    wxv = _cross(w, v)
    return v + f2 * wxv + f1 * _cross(w, wxv)


def head_rotation(q: np.ndarray) -> np.ndarray:
    """Head orientation matrices (N, 3, 3) of eq. 7: R_z(phi) R_y(theta) R_z(eps - phi)."""
    n = q.shape[0]
    kin = kinematics(q, 1.0)
    eps = q[:, 2]
    cols = np.stack([
        np.stack([np.cos(eps), np.sin(eps), np.zeros(n)], -1),
        np.stack([-np.sin(eps), np.cos(eps), np.zeros(n)], -1),
        np.tile([0.0, 0.0, 1.0], (n, 1)),
    ], axis=1)  # columns of R_z(eps), shape (N, 3 [col], 3)
    return np.swapaxes(rotate_bend(kin, cols), 1, 2)


def backbone_points(q: np.ndarray, length_m: float, n_points: int = 20) -> np.ndarray:
    """Points along the arc p(s), s in [0, l] (eq. 6), shape (N, n_points, 3). For drawing."""
    s = np.linspace(0.0, 1.0, n_points)
    out = []
    for frac in s:
        kin = kinematics(q * np.array([frac, frac, 0.0]), length_m * frac)
        out.append(kin.tip_m)
    return np.stack(out, axis=1)
