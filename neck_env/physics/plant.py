"""The whole neck as one batched plant: springs -> muscles -> backbone pose.

``PlantConstants.from_params`` turns one or many ``NeckParams`` into arrays (leading axis B = 1
or N rigs); ``initial_state`` and ``step`` are pure functions over a batch of N rigs.

Pose dynamics. Head inertia is neglected (250 g at ~0.1 m gives J ~ 3e-3 kg m^2 and a natural
frequency near 20 rad/s, far faster than the thermal time scale of seconds, and the TPU damps
it), leaving first-order viscous relaxation toward the moment balance of eq. 15::

    c * q_dot = Q_muscles(q) - K q,   K = diag(EI / l, EI / l, GJ / l)

integrated linearly-implicitly, ``q += dt * Q / (c + dt * K_eff)`` with ``K_eff`` the backbone
stiffness plus an estimate of the taut springs' stiffness. The fixed point is the exact
quasi-static balance; the step is stable for any dt.

Within a step the order is: spring extensions from the current pose -> thermal/phase update
(current, convection, latent heat, stress solved implicitly) -> spring forces -> pose update.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from ..params import NeckParams
from . import sma
from .backbone import bend_angles, kinematics
from .muscles import MuscleConstants, generalized_forces, muscle_geometry, spring_geometry

DEFAULT_DT_S = 0.01  # physics step; see tests/test_physics.py::test_step_convergence
SPRINGS_PER_MUSCLE = 2


class PlantConstants(NamedTuple):
    sma: sma.SMAConstants
    muscles: MuscleConstants
    length_m: np.ndarray  # (B,)
    bend_stiffness_Nm: np.ndarray  # (B, 1): EI / l
    twist_stiffness_Nm: np.ndarray  # (B, 1): GJ / l
    damping_Nms: np.ndarray  # (B, 1)
    lever_sq_m2: np.ndarray  # (B, 1): (r_h cos alpha)^2 / 2, for the implicit stiffness estimate
    n_rigs: int  # B

    @classmethod
    def from_params(cls, params: NeckParams | Sequence[NeckParams]) -> "PlantConstants":
        plist = [params] if isinstance(params, NeckParams) else list(params)
        if not plist:
            raise ValueError("from_params needs at least one NeckParams")

        def col(fn) -> np.ndarray:
            return np.array([[float(fn(p))] for p in plist])

        def sp(p):
            return p.spring

        def mat(p):
            return p.material

        G = lambda E, p: E / (2 * (1 + p.material.poisson_ratio))
        spring_mass = lambda p: p.material.density_kg_m3 * sp(p).wire_area_m2 * sp(p).wire_length_m
        wire_r = lambda p, rho: rho * sp(p).wire_length_m / sp(p).wire_area_m2
        sc = sma.SMAConstants(
            G_austenite_Pa=col(lambda p: G(mat(p).youngs_austenite_Pa, p)),
            G_martensite_Pa=col(lambda p: G(mat(p).youngs_martensite_Pa, p)),
            gamma_L=col(lambda p: sp(p).recoverable_shear_strain),
            shear_per_extension_1_m=col(lambda p: sp(p).wire_diameter_m
                                        / (math.pi * sp(p).active_coils * sp(p).coil_diameter_m**2)),
            force_per_shear_m2=col(lambda p: sp(p).force_per_shear_stress_m2),
            theta_shear_Pa_K=col(lambda p: mat(p).thermoelastic_Pa_per_K / math.sqrt(3)),
            As_C=col(lambda p: mat(p).As_C),
            Af_C=col(lambda p: mat(p).Af_C),
            Ms_C=col(lambda p: mat(p).Ms_C),
            Mf_C=col(lambda p: mat(p).Mf_C),
            C_A_Pa_K=col(lambda p: mat(p).C_A_Pa_per_K),
            C_M_Pa_K=col(lambda p: mat(p).C_M_Pa_per_K),
            heat_capacity_J_K=col(lambda p: spring_mass(p) * mat(p).specific_heat_J_kgK),
            latent_K=col(lambda p: mat(p).latent_heat_J_kg / mat(p).specific_heat_J_kgK),
            latent_J=col(lambda p: spring_mass(p) * mat(p).latent_heat_J_kg),
            R_martensite_ohm=col(lambda p: wire_r(p, mat(p).resistivity_martensite_ohm_m)),
            R_austenite_ohm=col(lambda p: wire_r(p, mat(p).resistivity_austenite_ohm_m)),
            hA_W_K=col(lambda p: p.thermal.convection_W_m2K * math.pi * sp(p).wire_diameter_m
                       * sp(p).wire_length_m),
            ambient_C=col(lambda p: p.thermal.ambient_C),
        )
        mcn = muscle_geometry(
            azimuths_deg=[p.muscles.azimuths_deg for p in plist],
            head_radius_m=[p.muscles.head_radius_m for p in plist],
            base_radius_m=[p.muscles.base_radius_m for p in plist],
            pennation_deg=[p.muscles.pennation_deg for p in plist],
            length_m=[p.backbone.length_m for p in plist],
            installed_extension_m=[sp(p).recoverable_extension_m + sp(p).pretension_extension_m
                                   for p in plist],
        )
        return cls(
            sma=sc,
            muscles=mcn,
            length_m=np.array([p.backbone.length_m for p in plist]),
            bend_stiffness_Nm=col(lambda p: p.backbone.bending_stiffness_Nm2 / p.backbone.length_m),
            twist_stiffness_Nm=col(lambda p: p.backbone.torsional_stiffness_Nm2 / p.backbone.length_m),
            damping_Nms=col(lambda p: p.backbone.damping_Nms_per_rad),
            lever_sq_m2=col(lambda p: 0.5 * (p.muscles.head_radius_m
                                             * math.cos(math.radians(p.muscles.pennation_deg))) ** 2),
            n_rigs=len(plist),
        )


class PlantState(NamedTuple):
    phase: sma.PhaseState  # springs, (N, 3) each
    q: np.ndarray  # (N, 3): bending vector (rad) and twist (rad)


class StepOutputs(NamedTuple):
    theta_deg: np.ndarray  # (N,)
    phi_deg: np.ndarray  # (N,) in [0, 360)
    power_W: np.ndarray  # (N, 3): electrical power of each muscle (both springs)
    muscle_force_N: np.ndarray  # (N, 3): tendon force magnitude
    convection_W: np.ndarray  # (N, 3): heat convected away by each muscle (both springs)


def initial_state(pc: PlantConstants, n_rigs: int | None = None) -> PlantState:
    """Upright neck, springs at ambient and fully martensite."""
    n = pc.n_rigs if n_rigs is None else n_rigs
    if pc.n_rigs not in (1, n):
        raise ValueError(f"constants are for {pc.n_rigs} rigs, state asked for {n}")
    return PlantState(sma.initial_phase_state(pc.sma, n), np.zeros((n, 3)))


def check_currents(current_A: np.ndarray, n_rigs: int) -> np.ndarray:
    """Validate currents: finite, shape (N, 3). Sign is irrelevant to Joule heating."""
    cur = np.asarray(current_A, dtype=float)
    if cur.shape != (n_rigs, 3):
        raise ValueError(f"currents must have shape ({n_rigs}, 3), got {cur.shape}")
    if not np.all(np.isfinite(cur)):
        raise ValueError(f"currents must be finite, got {cur[~np.isfinite(cur)][:3]}")
    return cur


def step(pc: PlantConstants, state: PlantState, current_A: np.ndarray, dt_s: float,
         extra_heat_W: np.ndarray | float = 0.0, hA_W_K: np.ndarray | None = None,
         extra_q_force: np.ndarray | float = 0.0) -> tuple[PlantState, StepOutputs]:
    """Advance N rigs by ``dt_s`` with muscle currents ``current_A`` (N, 3).

    ``extra_heat_W`` (per spring), ``hA_W_K`` and ``extra_q_force`` (N, 3) are hooks for the
    effect catalogue; the nominal plant uses none of them.
    """
    q = state.q
    cur = check_currents(current_A, q.shape[0])
    kin = kinematics(q, pc.length_m)
    geo = spring_geometry(pc.muscles, kin, q[:, 2])
    th = sma.phase_thermal_step(pc.sma, state.phase, cur, geo.extension_m.mean(axis=-1), dt_s,
                                extra_heat_W=extra_heat_W, hA_W_K=hA_W_K)
    ph = th.state
    forces = np.stack([sma.spring_force(pc.sma, geo.extension_m[..., s], ph.xi, ph.T_C)
                       for s in range(SPRINGS_PER_MUSCLE)], axis=-1)  # (N, 3, 2)
    q_force, f_muscle = generalized_forces(kin, geo, forces)
    stiffness = np.concatenate([pc.bend_stiffness_Nm, pc.bend_stiffness_Nm, pc.twist_stiffness_Nm], -1)
    q_force = q_force - stiffness * q + extra_q_force
    # Implicit-stiffness estimate from the taut springs (only shapes transients, not equilibria).
    k_spring = sma.spring_rate(pc.sma, ph.xi)[..., None] * (forces > 0)
    k_eff = stiffness + (k_spring.sum(axis=(1, 2)) * pc.lever_sq_m2[:, 0])[:, None]
    q_new = q + dt_s * q_force / (pc.damping_Nms + dt_s * k_eff)
    theta, phi = bend_angles(q_new)
    out = StepOutputs(
        theta_deg=np.rad2deg(theta),
        phi_deg=np.rad2deg(phi),
        power_W=SPRINGS_PER_MUSCLE * th.joule_W,
        muscle_force_N=np.linalg.norm(f_muscle, axis=-1),
        convection_W=SPRINGS_PER_MUSCLE * th.convection_W,
    )
    return PlantState(ph, q_new), out


class Trajectory(NamedTuple):
    """Time series of a batched simulation; leading axis is time (steps)."""

    t_s: np.ndarray  # (S,)
    theta_deg: np.ndarray  # (S, N)
    phi_deg: np.ndarray  # (S, N)
    T_C: np.ndarray  # (S, N, 3)
    xi: np.ndarray  # (S, N, 3)
    power_W: np.ndarray  # (S, N, 3)
    muscle_force_N: np.ndarray  # (S, N, 3)
    tau_Pa: np.ndarray | None = None


def simulate(pc: PlantConstants, currents_A: np.ndarray, dt_s: float = DEFAULT_DT_S,
             state: PlantState | None = None) -> tuple[Trajectory, PlantState]:
    """Run ``currents_A`` of shape (S, N, 3) (one row per step); returns the trajectory after
    each step (t = dt, 2 dt, ...) and the final state."""
    currents_A = np.asarray(currents_A, float)
    if currents_A.ndim != 3 or currents_A.shape[2] != 3:
        raise ValueError(f"currents_A must have shape (steps, rigs, 3), got {currents_A.shape}")
    n = currents_A.shape[1]
    st = initial_state(pc, n) if state is None else state
    rec = {k: [] for k in ("theta_deg", "phi_deg", "T_C", "xi", "power_W", "muscle_force_N")}
    for k in range(currents_A.shape[0]):
        st, out = step(pc, st, currents_A[k], dt_s)
        rec["theta_deg"].append(out.theta_deg)
        rec["phi_deg"].append(out.phi_deg)
        rec["T_C"].append(st.phase.T_C)
        rec["xi"].append(st.phase.xi)
        rec["power_W"].append(out.power_W)
        rec["muscle_force_N"].append(out.muscle_force_N)
    t = dt_s * np.arange(1, currents_A.shape[0] + 1)
    return Trajectory(t, *(np.array(rec[k]) for k in ("theta_deg", "phi_deg", "T_C", "xi",
                                                       "power_W", "muscle_force_N"))), st


def pulse_currents(current_A: Sequence[float] | np.ndarray, muscle: int, on_s: float,
                   total_s: float, dt_s: float = DEFAULT_DT_S) -> np.ndarray:
    """Currents (S, N, 3) for the paper's step experiment: muscle ``muscle`` (0-based) driven at
    ``current_A[n]`` for ``on_s`` seconds from t = 0, then off until ``total_s``."""
    amps = np.atleast_1d(np.asarray(current_A, float))
    steps = int(round(total_s / dt_s))
    on = (np.arange(steps) * dt_s) < on_s - 1e-9
    cur = np.zeros((steps, amps.size, 3))
    cur[:, :, muscle] = on[:, None] * amps[None, :]
    return cur
