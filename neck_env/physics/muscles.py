"""Bipennate muscle geometry and the moments they put on the head (paper eq. 11-14).

Muscle k sits at azimuth psi_k. Its tendon attaches to the head mount at radius r_h; its two
springs run from that point down to two base anchors at radius r_b, offset by +-w along the
tangent, with ``w = l tan(alpha)`` so the upright pennation angle is alpha. Each spring pulls
the tendon toward its own anchor, so the tendon force is ``F_k = 2 F_f cos(alpha)`` upright
(eq. 12) and the tangential parts cancel (they twist the head slightly once it is bent).

Moments: the head sees the net force ``F = sum F_k`` at the tip and the moment
``M = sum (p_k(l) - p(l)) x F_k`` about it (eq. 11); they enter the pose dynamics as
generalized forces by virtual work, ``Q_i = F . dp/dq_i + M . Omega_i``.
"""

from __future__ import annotations

import math

import numpy as np
from .compile import jit

from .backbone import rotate_bend
from .layout import ANCHOR, COS_PSI, FREE_LEN, HEAD_R, SIN_PSI


def anchor_geometry(azimuths_deg, head_radius_m: float, base_radius_m: float, pennation_deg: float,
                    length_m: float, installed_extension_m: float) -> tuple[np.ndarray, float]:
    """Base anchors (3 muscles, 2 springs, xyz) and the spring free length for one rig."""
    psi = np.deg2rad(np.asarray(azimuths_deg, float))
    radial = np.stack([np.cos(psi), np.sin(psi), np.zeros(3)], -1)
    tangent = np.stack([-np.sin(psi), np.cos(psi), np.zeros(3)], -1)
    w = length_m * math.tan(math.radians(pennation_deg))
    centre = base_radius_m * radial
    anchors = np.stack([centre + w * tangent, centre - w * tangent], axis=1)
    # Upright spring: from the tendon (r_h, height l) to an anchor (r_b, +-w, 0).
    upright = math.sqrt((head_radius_m - base_radius_m) ** 2 + length_m**2 + w**2)
    free = upright - installed_extension_m
    if free <= 0:
        raise ValueError(f"spring free length {free:.4f} m <= 0: the installed extension "
                         f"{installed_extension_m:.4f} m exceeds the upright spring length "
                         f"{upright:.4f} m (check spring.recoverable_shear_strain and geometry)")
    return anchors, free


@jit
def spring_geometry(c, bx, by, eps, f1, f2, tip, offset, unit, ext):
    """Fill tendon offsets p_k(l) - p(l) (3, 3), unit vectors tendon -> anchor (3, 2, 3) and
    spring extensions (3, 2) for one rig."""
    local = np.empty(3)
    ce, se = math.cos(eps), math.sin(eps)
    for k in range(3):
        cp, sp = c[COS_PSI + k], c[SIN_PSI + k]  # azimuth psi_k + twist eps
        local[0] = c[HEAD_R] * (cp * ce - sp * se)
        local[1] = c[HEAD_R] * (sp * ce + cp * se)
        local[2] = 0.0
        rotate_bend(bx, by, f1, f2, local, offset[k])
        for s in range(2):
            a = ANCHOR + 6 * k + 3 * s
            v0 = c[a] - tip[0] - offset[k, 0]
            v1 = c[a + 1] - tip[1] - offset[k, 1]
            v2 = c[a + 2] - tip[2] - offset[k, 2]
            length = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            inv = 1.0 / length
            unit[k, s, 0] = v0 * inv
            unit[k, s, 1] = v1 * inv
            unit[k, s, 2] = v2 * inv
            ext[k, s] = length - c[FREE_LEN]


@jit
def generalized_forces(forces, unit, offset, dtip, rot, q_force, f_muscle):
    """Generalized forces (3,) on q from spring tensions (3, 2); also tendon forces (3, 3)."""
    fx = fy = fz = 0.0
    mx = my = mz = 0.0
    for k in range(3):
        f0 = forces[k, 0] * unit[k, 0, 0] + forces[k, 1] * unit[k, 1, 0]
        f1 = forces[k, 0] * unit[k, 0, 1] + forces[k, 1] * unit[k, 1, 1]
        f2 = forces[k, 0] * unit[k, 0, 2] + forces[k, 1] * unit[k, 1, 2]
        f_muscle[k, 0], f_muscle[k, 1], f_muscle[k, 2] = f0, f1, f2
        fx += f0
        fy += f1
        fz += f2
        o = offset[k]
        mx += o[1] * f2 - o[2] * f1
        my += o[2] * f0 - o[0] * f2
        mz += o[0] * f1 - o[1] * f0
    for i in range(3):
        q_force[i] = (fx * dtip[i, 0] + fy * dtip[i, 1] + fz * dtip[i, 2]
                      + mx * rot[i, 0] + my * rot[i, 1] + mz * rot[i, 2])
