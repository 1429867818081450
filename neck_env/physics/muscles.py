"""Bipennate muscle geometry and the moments they put on the head (paper eq. 11-14).

Muscle k sits at azimuth psi_k. Its tendon attaches to the head mount at radius r_h
(``h_k`` in the head frame); its two springs run from that point down to two base anchors at
radius r_b, offset by +-w along the tangent, where ``w = l * tan(alpha)`` makes the pennation
angle alpha in the upright pose. Each spring pulls the tendon toward its own anchor, so the
muscle force along the tendon is ``F_k = 2 F_f cos(alpha)`` (eq. 12) while the tangential
components cancel in the upright pose (and twist the head slightly when it is bent).

Moments: the head sees the net force ``F = sum F_k`` at the tip and the moment
``M = sum (p_k(l) - p(l)) x F_k`` about it (eq. 11). They enter the pose dynamics as
generalized forces by virtual work, ``Q_i = F . dp/dq_i + M . Omega_i``.

Shapes: spring arrays are ``(N, 3 [muscle], 2 [spring])``; geometry constants carry a leading
batch axis B = 1 or N.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .backbone import BackboneKinematics, _cross, rotate_bend


class MuscleConstants(NamedTuple):
    head_points_local_m: np.ndarray  # (B, 3, 3): tendon attachment h_k in the untwisted head frame
    base_anchors_m: np.ndarray  # (B, 3, 2, 3)
    spring_free_length_m: np.ndarray  # (B, 1, 1): anchor-to-tendon length at zero extension
    head_radius_m: np.ndarray  # (B, 1)
    azimuths_rad: np.ndarray  # (B, 3)


def muscle_geometry(azimuths_deg, head_radius_m, base_radius_m, pennation_deg, length_m,
                    installed_extension_m) -> MuscleConstants:
    """Build the geometry constants for a batch of rigs (all arguments (B,) or (B, 3) arrays)."""
    psi = np.deg2rad(np.atleast_2d(np.asarray(azimuths_deg, float)))  # (B, 3)
    rh = np.atleast_1d(np.asarray(head_radius_m, float))[:, None]  # (B, 1)
    rb = np.atleast_1d(np.asarray(base_radius_m, float))[:, None]
    alpha = np.deg2rad(np.atleast_1d(np.asarray(pennation_deg, float)))[:, None]
    l = np.atleast_1d(np.asarray(length_m, float))[:, None]
    radial = np.stack([np.cos(psi), np.sin(psi), np.zeros_like(psi)], -1)  # (B, 3, 3)
    tangent = np.stack([-np.sin(psi), np.cos(psi), np.zeros_like(psi)], -1)
    head = rh[..., None] * radial
    w = (l * np.tan(alpha))[..., None]  # (B, 1, 1)
    base_center = rb[..., None] * radial
    anchors = np.stack([base_center + w * tangent, base_center - w * tangent], axis=2)  # (B,3,2,3)
    # Upright spring length: from the tendon point (r_h, height l) to an anchor (r_b +- w, 0).
    upright = np.sqrt((rh - rb) ** 2 + l**2 + (l * np.tan(alpha)) ** 2)  # (B, 1)
    inst = np.atleast_1d(np.asarray(installed_extension_m, float))[:, None]
    free = (upright - inst)[..., None]  # (B, 1, 1)
    if np.any(free <= 0):
        raise ValueError("spring free length <= 0: installed extension exceeds the upright "
                         "spring length (check spring.recoverable_shear_strain and geometry)")
    return MuscleConstants(head, anchors, free, rh, psi)


class MuscleGeometryState(NamedTuple):
    head_offset_m: np.ndarray  # (N, 3, 3): p_k(l) - p(l) in the world frame
    unit_to_anchor: np.ndarray  # (N, 3, 2, 3)
    spring_length_m: np.ndarray  # (N, 3, 2)
    extension_m: np.ndarray  # (N, 3, 2)


def spring_geometry(mc: MuscleConstants, kin: BackboneKinematics, eps: np.ndarray) -> MuscleGeometryState:
    """Where the tendons are and how far each spring is stretched, for poses ``kin``/``eps``."""
    psi = mc.azimuths_rad + eps[:, None]  # twist rotates the head points
    local = mc.head_radius_m[..., None] * np.stack([np.cos(psi), np.sin(psi), np.zeros_like(psi)], -1)
    offset = rotate_bend(kin, local)  # (N, 3, 3)
    tendon = kin.tip_m[:, None, :] + offset
    vec = mc.base_anchors_m - tendon[:, :, None, :]  # (N, 3, 2, 3)
    length = np.sqrt(np.einsum("...i,...i->...", vec, vec))
    unit = vec / length[..., None]
    return MuscleGeometryState(offset, unit, length, length - mc.spring_free_length_m)


def generalized_forces(kin: BackboneKinematics, geo: MuscleGeometryState,
                       spring_force_N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Generalized forces (N, 3) on q from spring tensions (N, 3, 2); also F_k vectors (N, 3, 3).

    The tendon force of muscle k is the sum of its two spring pulls (eq. 12 in vector form);
    the moment about the tip is eq. 11.
    """
    f_muscle = np.einsum("nks,nksi->nki", spring_force_N, geo.unit_to_anchor)  # (N, 3, 3)
    f_net = f_muscle.sum(axis=1)
    moment = _cross(geo.head_offset_m, f_muscle).sum(axis=1)
    q_force = np.einsum("ni,nqi->nq", f_net, kin.dtip_dq) + np.einsum("ni,nqi->nq", moment, kin.rot_axis_dq)
    return q_force, f_muscle
