"""SMA spring thermo-mechanics (paper eq. 1-5) as pure functions over batched arrays.

Shapes: every array argument broadcasts against the spring batch, normally ``(N, 3)`` (N rigs,
one representative spring per muscle; the two springs of a muscle are identical). Material
constants are ``(B, 1)`` with B = 1 or N, so a batch of rigs may carry its own parameters.

Constitutive law (eq. 1-2). The paper writes Tanaka/Brinson's rate law
``tau_dot = A gamma_dot + B xi_dot + C T_dot`` with ``A = d^4 G / (8 n D^3)`` etc. We integrate
it in the standard consistent form

    tau = G(xi) * (gamma - gamma_L * xi) + Theta_s * (T - T_ref),   G(xi) = E(xi) / (2 (1 + nu))

whose time derivative is eq. 1 with ``B = G'(xi) (gamma - gamma_L xi) - G gamma_L`` (Brinson's
phase-dependent Omega) -- no drift from integrating a rate law. The spring force is
``F = pi d^3 / (8 D) * tau`` and ``gamma = d * delta / (pi n D^2)``, so a spring of fixed phase has
the rate ``d^4 G / (8 n D^3)`` of eq. 1. Springs carry tension only: ``tau`` is clipped at 0
(a slack spring pushes nothing).

Phase kinetics (eq. 3-4, cosine model with stress-shifted temperatures
``A_s' = A_s + tau / C_A`` etc.; eq. 4 as corrected in the design notes). Partial-transformation
memory: the branch taken after a reversal is scaled to pass through the reversal point
``(T_r, xi_r)``, so xi is continuous through reversals and a reversal mid-transformation follows
a minor loop. When the reversal happens outside the transformation band the branch is exactly
the paper's (``xi_m = xi_r`` on heating, ``xi_a = xi_r`` on cooling). On heating xi can only fall
and on cooling only rise.

Energy balance (eq. 5): ``m c_p T_dot = I^2 R(xi) - h A (T - T_amb) + m dH xi_dot`` with
``R = R_m xi + R_a (1 - xi)``. One step: convection implicit, latent heat and stress solved
together with xi (the phase-stress coupling is stiff, a lagged stress overshoots), so the step is
stable for any dt and conserves energy to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

_TINY = 1e-12
NEWTON_ITERATIONS = 30  # cap of the safeguarded Newton; typically 2-4 iterations are used


class SMAConstants(NamedTuple):
    """Per-rig spring constants, each shaped ``(B, 1)``. Units in the names."""

    G_austenite_Pa: np.ndarray
    G_martensite_Pa: np.ndarray
    gamma_L: np.ndarray  # recoverable shear strain
    shear_per_extension_1_m: np.ndarray  # d / (pi n D^2)
    force_per_shear_m2: np.ndarray  # pi d^3 / (8 D)
    theta_shear_Pa_K: np.ndarray  # thermoelastic coefficient in shear
    As_C: np.ndarray
    Af_C: np.ndarray
    Ms_C: np.ndarray
    Mf_C: np.ndarray
    C_A_Pa_K: np.ndarray
    C_M_Pa_K: np.ndarray
    heat_capacity_J_K: np.ndarray  # m c_p of one spring
    latent_K: np.ndarray  # dH / c_p: temperature change per unit xi change
    latent_J: np.ndarray  # m dH of one spring
    R_martensite_ohm: np.ndarray  # one spring
    R_austenite_ohm: np.ndarray
    hA_W_K: np.ndarray  # convection coefficient times wire surface
    ambient_C: np.ndarray


class PhaseState(NamedTuple):
    """Thermal and phase state of the springs, each ``(N, 3)``."""

    T_C: np.ndarray
    xi: np.ndarray  # martensite volume fraction in [0, 1]
    heating: np.ndarray  # bool: branch in use (True = reverse transformation M -> A)
    branch_scale: np.ndarray  # scale of the branch through the last reversal point


def shear_modulus(c: SMAConstants, xi: np.ndarray) -> np.ndarray:
    """G(xi) of eq. 2 (E interpolated in xi, G = E / 2(1+nu), nu folded into the constants)."""
    return c.G_austenite_Pa + (c.G_martensite_Pa - c.G_austenite_Pa) * xi


def shear_stress(c: SMAConstants, extension_m: np.ndarray, xi: np.ndarray,
                 T_C: np.ndarray) -> np.ndarray:
    """Wire shear stress (Pa) of the integrated eq. 1, tension only."""
    gamma = extension_m * c.shear_per_extension_1_m
    tau = shear_modulus(c, xi) * (gamma - c.gamma_L * xi) + c.theta_shear_Pa_K * (T_C - c.ambient_C)
    return np.maximum(tau, 0.0)


def _dstress_dxi(c: SMAConstants, extension_m: np.ndarray, xi: np.ndarray,
                 tau: np.ndarray) -> np.ndarray:
    gamma = extension_m * c.shear_per_extension_1_m
    d = (c.G_martensite_Pa - c.G_austenite_Pa) * (gamma - c.gamma_L * xi) - shear_modulus(c, xi) * c.gamma_L
    return np.where(tau > 0.0, d, 0.0)


def spring_force(c: SMAConstants, extension_m: np.ndarray, xi: np.ndarray,
                 T_C: np.ndarray) -> np.ndarray:
    """Axial force (N) of one spring: pi d^3 / (8 D) * tau."""
    return c.force_per_shear_m2 * shear_stress(c, extension_m, xi, T_C)


def spring_rate(c: SMAConstants, xi: np.ndarray) -> np.ndarray:
    """Spring rate (N/m) at fixed phase: d^4 G(xi) / (8 n D^3) (eq. 1, A)."""
    return shear_modulus(c, xi) * c.shear_per_extension_1_m * c.force_per_shear_m2


def resistance(c: SMAConstants, xi: np.ndarray) -> np.ndarray:
    """Phase-dependent resistance of one spring (ohm), eq. 5."""
    return c.R_martensite_ohm * xi + c.R_austenite_ohm * (1.0 - xi)


def _cos_band(x: np.ndarray, start: np.ndarray, width: np.ndarray):
    """(1 - cos(pi u)) / 2 and its derivative in x, with u = (x - start) / width clipped to [0, 1]."""
    u = (x - start) / width
    inside = (u > 0.0) & (u < 1.0)
    u = np.clip(u, 0.0, 1.0)
    val = 0.5 * (1.0 - np.cos(np.pi * u))
    dval = np.where(inside, 0.5 * np.pi / width * np.sin(np.pi * u), 0.0)
    return val, dval


def reverse_shape(c: SMAConstants, T_C, tau):
    """Heating branch shape g in [0, 1] (eq. 3 divided by xi_m) and dg/dx, x = T - tau / C_A.

    g = 1 below A_s', 0 above A_f', (cos(a_A (T - A_s')) + 1) / 2 between.
    """
    x = T_C - tau / c.C_A_Pa_K
    val, dval = _cos_band(x, c.As_C, c.Af_C - c.As_C)
    return 1.0 - val, -dval


def forward_shape(c: SMAConstants, T_C, tau):
    """Cooling branch shape p in [0, 1] and dp/dx, x = T - tau / C_M: xi = 1 - (1 - xi_a) p.

    p = 1 above M_s', 0 below M_f'; this is eq. 4 (corrected) with p = (1 - cos(a_M (T - M_f'))) / 2.
    """
    x = T_C - tau / c.C_M_Pa_K
    return _cos_band(x, c.Mf_C, c.Ms_C - c.Mf_C)


def initial_phase_state(c: SMAConstants, n_rigs: int, n_muscles: int = 3) -> PhaseState:
    """Springs at ambient temperature, fully martensite, on the cooling branch."""
    T = np.broadcast_to(c.ambient_C, (n_rigs, n_muscles)).astype(float).copy()
    return PhaseState(
        T_C=T,
        xi=np.ones((n_rigs, n_muscles)),
        heating=np.zeros((n_rigs, n_muscles), dtype=bool),
        branch_scale=np.zeros((n_rigs, n_muscles)),
    )


class ThermalStep(NamedTuple):
    """Result of one thermal/phase step. Powers are per spring (W)."""

    state: PhaseState
    joule_W: np.ndarray  # I^2 R(xi) at the start of the step
    convection_W: np.ndarray  # h A (T - T_amb), implicit (end-of-step convective temperature)
    tau_Pa: np.ndarray  # shear stress consistent with the new xi


def phase_thermal_step(c: SMAConstants, s: PhaseState, current_A: np.ndarray,
                       extension_m: np.ndarray, dt_s: float,
                       extra_heat_W: np.ndarray | float = 0.0,
                       hA_W_K: np.ndarray | None = None) -> ThermalStep:
    """Advance temperature and martensite fraction by ``dt_s`` at fixed spring extension.

    ``current_A`` (N, 3) flows through each spring. ``extra_heat_W`` is heat from outside the
    model (used by the effect catalogue, e.g. heat exchanged between muscles); ``hA_W_K``
    overrides the convection coefficient (e.g. a draft).
    """
    hA = c.hA_W_K if hA_W_K is None else hA_W_K
    joule = current_A * current_A * resistance(c, s.xi)
    mc = c.heat_capacity_J_K
    # Implicit convection: stable for any dt, exact steady state.
    T_star = (s.T_C + dt_s / mc * (joule + extra_heat_W + hA * c.ambient_C)) / (1.0 + dt_s * hA / mc)
    convection = hA * (T_star - c.ambient_C)

    heating = T_star > s.T_C
    # Temperature steady to round-off: keep the branch (no spurious reversals).
    heating = np.where(np.abs(T_star - s.T_C) <= 1e-12 * np.abs(s.T_C), s.heating, heating)
    reversed_ = heating != s.heating
    tau_old = shear_stress(c, extension_m, s.xi, s.T_C)
    # Re-anchor the branch at the reversal point so xi stays continuous (minor loops).
    g_r, _ = reverse_shape(c, s.T_C, tau_old)
    p_r, _ = forward_shape(c, s.T_C, tau_old)
    scale_heat = s.xi / np.maximum(g_r, _TINY)
    scale_cool = (1.0 - s.xi) / np.maximum(p_r, _TINY)
    scale = np.where(reversed_, np.where(heating, scale_heat, scale_cool), s.branch_scale)

    xi = _solve_phase(c, s.xi, T_star, extension_m, heating, scale)
    T_new = T_star + c.latent_K * (xi - s.xi)
    tau = shear_stress(c, extension_m, xi, T_new)
    return ThermalStep(PhaseState(T_new, xi, heating, scale), joule, convection, tau)


def _branch(c: SMAConstants, xi, T_star, xi_old, extension_m, heating, scale):
    """h(xi) = xi - branch(x(xi)) and dh/dxi, with latent heat and stress following xi."""
    T = T_star + c.latent_K * (xi - xi_old)
    tau = shear_stress(c, extension_m, xi, T)
    dtau = _dstress_dxi(c, extension_m, xi, tau) + np.where(tau > 0, c.theta_shear_Pa_K * c.latent_K, 0.0)
    g, dg = reverse_shape(c, T, tau)
    p, dp = forward_shape(c, T, tau)
    dx_heat = c.latent_K - dtau / c.C_A_Pa_K
    dx_cool = c.latent_K - dtau / c.C_M_Pa_K
    target = np.where(heating, scale * g, 1.0 - scale * p)
    dtarget = np.where(heating, scale * dg * dx_heat, -scale * dp * dx_cool)
    return xi - target, 1.0 - dtarget


def _solve_phase(c: SMAConstants, xi_old, T_star, extension_m, heating, scale):
    """Solve xi = branch(T(xi), tau(xi)) within the branch's monotone bracket.

    On heating xi lies in [0, xi_old], on cooling in [xi_old, 1]; h is increasing in xi there
    (stress and latent heat both push the effective temperature the same way), so a bracketed,
    safeguarded Newton converges. If the branch does not call for transformation, xi stays.
    """
    lo = np.where(heating, 0.0, xi_old)
    hi = np.where(heating, xi_old, 1.0)
    h_start, _ = _branch(c, xi_old, T_star, xi_old, extension_m, heating, scale)
    # Heating with h(xi_old) <= 0 (branch above xi_old) or cooling with h >= 0: no transformation.
    moves = np.where(heating, h_start > 0.0, h_start < 0.0)
    if not np.any(moves):
        return xi_old.copy() if isinstance(xi_old, np.ndarray) else xi_old
    idx = np.nonzero(moves)
    sub = SMAConstants(*(np.broadcast_to(v, xi_old.shape)[idx] for v in c))
    x_old = xi_old[idx]
    args = (T_star[idx], x_old, extension_m[idx], heating[idx], scale[idx])
    lo_s, hi_s = lo[idx], hi[idx]
    # Start from xi_old: a step rarely moves xi far, so Newton from there converges in a few
    # iterations; the bracket catches the steps that overshoot a band edge.
    x = x_old
    for _ in range(NEWTON_ITERATIONS):
        h, dh = _branch(sub, x, *args)
        if np.all(np.abs(h) < 1e-13):
            break
        lo_s = np.where(h < 0.0, x, lo_s)
        hi_s = np.where(h > 0.0, x, hi_s)
        newton = x - h / dh
        ok = (newton >= lo_s) & (newton <= hi_s)
        x = np.where(ok, newton, 0.5 * (lo_s + hi_s))
    xi = xi_old.copy()
    xi[idx] = x
    return xi
