"""SMA spring thermo-mechanics (paper eq. 1-5), compiled scalar functions of one spring.

``c`` is one row of the packed constants (``layout``); the plant calls these for every rig.

Constitutive law (eq. 1-2). The paper writes Tanaka/Brinson's rate law
``tau_dot = A gamma_dot + B xi_dot + C T_dot`` with ``A = d^4 G / (8 n D^3)`` etc. We use it in
the standard integrated form

    tau = G(xi) * (gamma - gamma_L * xi) + Theta_s * (T - T_amb),   G(xi) = E(xi) / (2 (1 + nu))

whose time derivative is eq. 1 with ``B = G'(xi) (gamma - gamma_L xi) - G gamma_L`` (Brinson's
phase-dependent Omega) -- no drift from integrating a rate law. Spring force
``F = pi d^3 / (8 D) * tau``, shear strain ``gamma = d * delta / (pi n D^2)``, so a spring of
fixed phase has the rate ``d^4 G / (8 n D^3)`` of eq. 1. Springs carry tension only: ``tau`` is
clipped at 0 (a slack spring pushes nothing).

Phase kinetics (eq. 3-4, cosine model, stress-shifted ``A_s' = A_s + tau / C_A`` etc., eq. 4
as corrected in the design notes). Partial-transformation memory: at a heating/cooling reversal
the new branch is scaled to pass through the reversal point ``(T_r, xi_r)``, so xi is continuous
and a reversal mid-transformation follows a minor loop. A reversal outside the band gives the
paper's branch exactly (``xi_m = xi_r`` on heating, ``xi_a = xi_r`` on cooling). On heating xi
can only fall, on cooling only rise.

Energy balance (eq. 5): ``m c_p T_dot = I^2 R(xi) - h A (T - T_amb) + m dH xi_dot`` with
``R = R_m xi + R_a (1 - xi)``. One step integrates Joule heat and convection exactly for the
step's power (exponential integrator), then solves xi, the stress and the latent heat together:
the phase-stress coupling is stiff (a lagged stress overshoots by an order of magnitude).
"""

from __future__ import annotations

import math

import numpy as np
from .compile import jit

from .layout import (AMBIENT, AS, FORCE_PER_SHEAR, G_A, G_M, GAMMA_L, HEAT_CAP, INV_BAND_A,
                     INV_BAND_M, INV_C_A, INV_C_M, LATENT_K, MF, R_A, R_M, SHEAR_PER_EXT,
                     THETA_SHEAR)

_TINY = 1e-12
NEWTON_ITERATIONS = 30  # cap of the safeguarded Newton; 2-4 iterations are typical
NEWTON_TOL = 1e-11  # on xi; far below anything observable


@jit
def shear_modulus(c, xi):
    """G(xi) of eq. 2 (E interpolated in xi; nu folded into G_A, G_M)."""
    return c[G_A] + (c[G_M] - c[G_A]) * xi


@jit
def shear_stress(c, ext, xi, T, gamma_L):
    """Wire shear stress (Pa) of the integrated eq. 1, tension only."""
    gamma = ext * c[SHEAR_PER_EXT]
    tau = shear_modulus(c, xi) * (gamma - gamma_L * xi) + c[THETA_SHEAR] * (T - c[AMBIENT])
    return tau if tau > 0.0 else 0.0


@jit
def spring_force(c, ext, xi, T, gamma_L):
    """Axial force of one spring (N): pi d^3 / (8 D) * tau."""
    return c[FORCE_PER_SHEAR] * shear_stress(c, ext, xi, T, gamma_L)


@jit
def spring_rate(c, xi):
    """Spring rate at fixed phase (N/m): d^4 G(xi) / (8 n D^3) (eq. 1, A)."""
    return shear_modulus(c, xi) * c[SHEAR_PER_EXT] * c[FORCE_PER_SHEAR]


@jit
def resistance(c, xi):
    """Phase-dependent resistance of one spring (ohm), eq. 5."""
    return c[R_M] * xi + c[R_A] * (1.0 - xi)


@jit
def _cos_band(x, start, inv_width):
    """(1 - cos(pi u)) / 2 and its x-derivative, u = (x - start) / width clipped to [0, 1]."""
    u = (x - start) * inv_width
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    cu = math.cos(math.pi * u)
    # sin(pi u) >= 0 on (0, 1): take it from cos (a sqrt is cheaper than a second sin/cos).
    return 0.5 * (1.0 - cu), 0.5 * math.pi * inv_width * math.sqrt(max(1.0 - cu * cu, 0.0))


@jit
def reverse_shape(c, T, tau):
    """Heating branch g in [0, 1] (eq. 3 / xi_m) and dg/dx at x = T - tau / C_A."""
    v, dv = _cos_band(T - tau * c[INV_C_A], c[AS], c[INV_BAND_A])
    return 1.0 - v, -dv


@jit
def forward_shape(c, T, tau):
    """Cooling branch p in [0, 1] and dp/dx at x = T - tau / C_M; xi = 1 - (1 - xi_a) p (eq. 4)."""
    return _cos_band(T - tau * c[INV_C_M], c[MF], c[INV_BAND_M])


@jit
def _branch(c, xi, T_star, xi_old, ext, heating, scale, gamma_L):
    """h(xi) = xi - branch(x(xi)) and dh/dxi; temperature and stress follow xi."""
    T = T_star + c[LATENT_K] * (xi - xi_old)
    tau = shear_stress(c, ext, xi, T, gamma_L)
    if tau > 0.0:
        gamma = ext * c[SHEAR_PER_EXT]
        dtau = ((c[G_M] - c[G_A]) * (gamma - gamma_L * xi) - shear_modulus(c, xi) * gamma_L
                + c[THETA_SHEAR] * c[LATENT_K])
    else:
        dtau = 0.0
    if heating:
        g, dg = reverse_shape(c, T, tau)
        return xi - scale * g, 1.0 - scale * dg * (c[LATENT_K] - dtau * c[INV_C_A])
    p, dp = forward_shape(c, T, tau)
    return xi - (1.0 - scale * p), 1.0 + scale * dp * (c[LATENT_K] - dtau * c[INV_C_M])


@jit
def solve_phase(c, xi_old, T_star, ext, heating, scale, gamma_L):
    """xi consistent with its branch at the new temperature, stress and latent heat.

    h(xi) is increasing on the branch's bracket ([0, xi_old] heating, [xi_old, 1] cooling):
    stress and latent heat both move the effective temperature the same way as xi. If the
    branch asks for no transformation, xi stays. Bracketed Newton from xi_old.
    """
    h, dh = _branch(c, xi_old, T_star, xi_old, ext, heating, scale, gamma_L)
    if (heating and h <= 0.0) or ((not heating) and h >= 0.0):
        return xi_old
    lo, hi = (0.0, xi_old) if heating else (xi_old, 1.0)
    x = xi_old
    for _ in range(NEWTON_ITERATIONS):
        if abs(h) < NEWTON_TOL:
            break
        if h < 0.0:
            lo = x
        else:
            hi = x
        xn = x - h / dh
        if not (lo <= xn <= hi):
            xn = 0.5 * (lo + hi)
        x = xn
        h, dh = _branch(c, x, T_star, xi_old, ext, heating, scale, gamma_L)
    return x


@jit
def phase_thermal_step(c, T, xi, heating, scale, current, ext, dt, extra_heat, hA, decay, gamma_L):
    """Advance one spring by dt at fixed extension.

    Returns (T, xi, heating, scale, joule_J, convected_J): the new state and the heat of the
    step. ``extra_heat`` (W) comes from outside the model (effects, e.g. a neighbour muscle);
    ``hA`` (W/K) is the convection coefficient in force (nominal or changed by an effect) and
    ``decay = exp(-dt hA / (m c_p))`` its factor over the step (the caller shares it between
    springs with the same hA).
    """
    joule_W = current * current * resistance(c, xi)
    power = joule_W + extra_heat
    mc = c[HEAT_CAP]
    T_eq = c[AMBIENT] + power / hA
    T_star = T_eq + (T - T_eq) * decay
    convected = power * dt - mc * (T_star - T)  # exact for the step's constant power
    if T_star > T:
        heat_new = True
    elif T_star < T:
        heat_new = False
    else:
        heat_new = heating  # steady: no spurious reversal
    if heat_new != heating:
        # Re-anchor the branch at the reversal point so xi stays continuous (minor loops).
        tau_r = shear_stress(c, ext, xi, T, gamma_L)
        if heat_new:
            g, _ = reverse_shape(c, T, tau_r)
            scale = xi / max(g, _TINY)
        else:
            p, _ = forward_shape(c, T, tau_r)
            scale = (1.0 - xi) / max(p, _TINY)
    xi_new = solve_phase(c, xi, T_star, ext, heat_new, scale, gamma_L)
    T_new = T_star + c[LATENT_K] * (xi_new - xi)
    return T_new, xi_new, heat_new, scale, joule_W * dt, convected


# --- batched conveniences (tests, plots): loops run compiled -------------------------------

@jit
def _map3(fn_id, consts, a, b, cc):
    out = np.empty(a.shape)
    fa, fb, fc, fo = a.ravel(), b.ravel(), cc.ravel(), out.ravel()
    n_rows = consts.shape[0]
    per_row = fa.size // n_rows if n_rows > 1 else fa.size
    for i in range(fa.size):
        c = consts[i // per_row] if n_rows > 1 else consts[0]
        if fn_id == 0:
            fo[i] = spring_force(c, fa[i], fb[i], fc[i], c[GAMMA_L])
        elif fn_id == 1:
            fo[i] = spring_rate(c, fb[i])
        else:
            fo[i] = resistance(c, fb[i])
    return out


def spring_force_batch(consts: np.ndarray, ext_m: np.ndarray, xi: np.ndarray, T_C: np.ndarray) -> np.ndarray:
    """Spring force (N) for arrays of a common shape whose leading axis is the rig (or 1 rig)."""
    ext, xi, T = np.broadcast_arrays(*(np.asarray(v, float) for v in (ext_m, xi, T_C)))
    return _map3(0, consts, ext.copy(), xi.copy(), T.copy())


def spring_rate_batch(consts: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Spring rate (N/m) at fixed phase for an array of xi (leading axis: rig)."""
    xi = np.asarray(xi, float)
    return _map3(1, consts, xi, xi, xi)


def resistance_batch(consts: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Resistance of one spring (ohm) for an array of xi (leading axis: rig)."""
    xi = np.asarray(xi, float)
    return _map3(2, consts, xi, xi, xi)
