"""Control allocation: a desired bending vector onto the three muscles.

The head bends toward a heated muscle, so muscle k "pulls" the tilt vector along its unit vector
``u_k = (cos psi_k, sin psi_k)`` (azimuths 180, 60, 300 deg by default). Muscles pull and never
push: a muscle's share must be >= 0.

* ``allocate_pull(v)`` -- the non-negative split: any planar vector lies in the 120 deg sector
  of two adjacent muscles and is a unique non-negative combination of their two unit vectors
  (the third muscle gets 0). ``resultant(allocate_pull(v)) == v``.
* ``allocate_signed(v)`` -- the minimum-norm signed split ``(2/3) U^T v`` (shares sum to zero):
  a correction that raises some muscles and lowers others around an operating point, as a PID
  adds to its feedforward. The caller clips the sum to >= 0.

All functions take vectors in any unit (degrees of tilt, watts of drive, ...); the split is
linear in ``v``.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

MUSCLE_AZIMUTHS_DEG = (180.0, 60.0, 300.0)


def muscle_unit_vectors(azimuths_deg: Sequence[float] = MUSCLE_AZIMUTHS_DEG) -> np.ndarray:
    """(3, 2) unit vectors of the muscle directions."""
    a = np.radians(np.asarray(azimuths_deg, dtype=float))
    if a.shape != (3,):
        raise ValueError(f"need three azimuths, got {a.shape}")
    return np.stack([np.cos(a), np.sin(a)], axis=1)


def resultant(shares: np.ndarray, azimuths_deg: Sequence[float] = MUSCLE_AZIMUTHS_DEG) -> np.ndarray:
    """The bending vector ``sum_k shares_k u_k`` (2,)."""
    return np.asarray(shares, dtype=float) @ muscle_unit_vectors(azimuths_deg)


def allocate_pull(vec, azimuths_deg: Sequence[float] = MUSCLE_AZIMUTHS_DEG) -> np.ndarray:
    """Non-negative muscle shares (3,) whose resultant is ``vec`` (2,).

    The two muscles whose directions bracket ``vec`` share it (solved exactly as a 2x2 system);
    the third gets 0. A vector along a muscle goes to that muscle alone. Works for any three
    azimuths whose unit vectors positively span the plane (no gap of 180 deg or more).
    """
    v = np.asarray(vec, dtype=float).reshape(2)
    out = np.zeros(3)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"bending vector must be finite, got {v}")
    if v[0] == 0.0 and v[1] == 0.0:
        return out
    az = np.mod(np.asarray(azimuths_deg, dtype=float), 360.0)
    order = np.argsort(az)
    direction = math.degrees(math.atan2(v[1], v[0])) % 360.0
    for j in range(3):
        a, b = order[j], order[(j + 1) % 3]
        span = (az[b] - az[a]) % 360.0
        if span >= 180.0:
            raise ValueError(f"azimuths {tuple(azimuths_deg)} leave a gap of >= 180 deg; "
                             "the muscles cannot bend the neck every way")
        if (direction - az[a]) % 360.0 <= span:
            u = muscle_unit_vectors(azimuths_deg)
            m = np.array([[u[a, 0], u[b, 0]], [u[a, 1], u[b, 1]]])
            wa, wb = np.linalg.solve(m, v)
            out[a], out[b] = max(wa, 0.0), max(wb, 0.0)
            return out
    raise AssertionError("unreachable: every direction lies in some sector")


def allocate_signed(vec, azimuths_deg: Sequence[float] = MUSCLE_AZIMUTHS_DEG) -> np.ndarray:
    """Minimum-norm signed shares (3,) with resultant ``vec`` (for symmetric layouts, where
    ``U^T U = (3/2) I``; in general the least-norm solution ``U (U^T U)^-1 v``)."""
    v = np.asarray(vec, dtype=float).reshape(2)
    u = muscle_unit_vectors(azimuths_deg)
    return u @ np.linalg.solve(u.T @ u, v)
