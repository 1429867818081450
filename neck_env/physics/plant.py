"""The whole neck as one batched plant: springs -> muscles -> backbone pose.

Data: packed float64 arrays (column layout in ``layout``): constants ``(B, N_CONST)`` from
``constants_from_params`` (B = 1 shares one parameter row among all rigs), state
``(N, N_STATE)`` from ``initial_state``, outputs ``(N, N_OUT)``. ``step`` is a pure function of
them; ``step_inplace`` is the allocation-free form the environments use. One compiled call
advances all N rigs (parallel over rigs for large N); no Python loop runs over rigs.

Pose dynamics. Head inertia is neglected (250 g at ~0.1 m gives J ~ 3e-3 kg m^2 and a natural
frequency near 20 rad/s, far faster than the thermal seconds, and the TPU damps it). The pose
relaxes viscously toward the moment balance of eq. 15::

    c q_dot = Q_muscles(q) - K q  (+ effect terms),   K = diag(EI / l, EI / l, GJ / l)

integrated by exponential Euler with ``K_eff`` = backbone stiffness plus an estimate of the taut
springs' stiffness: ``q += (1 - exp(-dt K_eff / c)) Q / K_eff``. The fixed point is the exact
quasi-static balance and the step is stable for any dt.

Order within a step: spring extensions from the current pose -> currents (supply limit, energy
budget) -> thermal/phase update per muscle (Joule heat, convection, heat drained into the
muscle's terminals, latent heat and stress solved together; then the terminals) -> spring
forces -> pose update.

Energy budget: ``energy_left_J`` (N,) is debited by the electrical energy of every substep; a
substep that would overdraw it has its currents scaled so that exactly the remainder is spent,
so the budget is never exceeded and actuation stops once it is gone.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
from numba import prange

from .compile import jit

from ..params import NeckParams
from .backbone import bend_angles, kinematics
from .layout import (AF, AMBIENT, ANCHOR, AS, C_A, C_M, CONV_EXP, CONV_GAIN, CONV_MIN_DT_K,
                     CONV_REF_DT_K, CONV_TCOEF, COS_PSI, COUPLING,
                     CUTOFF_C,
                     INV_BAND_A, INV_BAND_M, INV_C_A, INV_C_M,
                     DAMPING, FATIGUE_MAX, FATIGUE_RATE, FORCE_PER_SHEAR, FREE_LEN, FRICTION,
                     G_A, G_M, GAMMA_L, HA, HEAD_R, HEAT_CAP, K_BEND, K_TWIST, LATENT_J,
                     LATENT_K, LENGTH, LEVER_SQ, MF, MS, N_CONST, N_OUT, N_STATE, O_CONV,
                     O_CURRENT, O_ENERGY, O_FORCE, O_PHI, O_POWER, O_THETA, PAYLOAD_COM,
                     PAYLOAD_MG, PSI, R_A, R_M, SIN_PSI, S_FATIGUE, S_HEAT, S_Q, S_SCALE, S_T, S_TERM,
                     S_VISCO, TERM_C, TERM_G, TERM_LOSS,
                     S_XI, SHEAR_PER_EXT, SUPPLY_V, THETA_SHEAR, VISCO_K, VISCO_TAU, WIRING_R)
from .muscles import anchor_geometry, generalized_forces, spring_geometry
from .sma import phase_thermal_step, resistance, spring_force, spring_rate

# Physics step for experiments and calibration (the envs step at their control period,
# neck_env.task.CONTROL_DT_S); convergence in tests/test_physics.py.
EXPERIMENT_DT_S = 0.01
SPRINGS_PER_MUSCLE = 2
PARALLEL_FROM = 512  # rigs; below this the thread start-up costs more than it saves
PARALLEL_CHUNK = 64  # rigs per parallel work item (a loop over rigs in prange splits into these)


def constants_from_params(params: NeckParams | Sequence[NeckParams]) -> np.ndarray:
    """Pack one or many parameter sets into a ``(B, N_CONST)`` constants array (effects off)."""
    plist = [params] if isinstance(params, NeckParams) else list(params)
    if not plist:
        raise ValueError("constants_from_params needs at least one NeckParams")
    out = np.empty((len(plist), N_CONST))
    for row, p in zip(out, plist):
        sp, mat = p.spring, p.material
        G = lambda E: E / (2 * (1 + mat.poisson_ratio))
        mass = mat.density_kg_m3 * sp.wire_area_m2 * sp.wire_length_m
        row[G_A] = G(mat.youngs_austenite_Pa)
        row[G_M] = G(mat.youngs_martensite_Pa)
        row[GAMMA_L] = sp.recoverable_shear_strain
        row[SHEAR_PER_EXT] = sp.wire_diameter_m / (math.pi * sp.active_coils * sp.coil_diameter_m**2)
        row[FORCE_PER_SHEAR] = sp.force_per_shear_stress_m2
        row[THETA_SHEAR] = mat.thermoelastic_Pa_per_K / math.sqrt(3)
        row[AS], row[AF], row[MS], row[MF] = mat.As_C, mat.Af_C, mat.Ms_C, mat.Mf_C
        row[C_A], row[C_M] = mat.C_A_Pa_per_K, mat.C_M_Pa_per_K
        row[HEAT_CAP] = mass * mat.specific_heat_J_kgK
        row[LATENT_K] = mat.latent_heat_J_kg / mat.specific_heat_J_kgK
        row[LATENT_J] = mass * mat.latent_heat_J_kg
        row[R_M] = mat.resistivity_martensite_ohm_m * sp.wire_length_m / sp.wire_area_m2
        row[R_A] = mat.resistivity_austenite_ohm_m * sp.wire_length_m / sp.wire_area_m2
        row[HA] = p.thermal.convection_W_m2K * sp.surface_m2
        row[AMBIENT] = p.thermal.ambient_C
        bb, mu = p.backbone, p.muscles
        row[LENGTH] = bb.length_m
        row[K_BEND] = bb.bending_stiffness_Nm2 / bb.length_m
        row[K_TWIST] = bb.torsional_stiffness_Nm2 / bb.length_m
        row[DAMPING] = bb.damping_Nms_per_rad
        row[LEVER_SQ] = 0.5 * (mu.head_radius_m * math.cos(math.radians(mu.pennation_deg))) ** 2
        row[HEAD_R] = mu.head_radius_m
        row[PSI:PSI + 3] = np.deg2rad(mu.azimuths_deg)
        anchors, free = anchor_geometry(mu.azimuths_deg, mu.head_radius_m, mu.base_radius_m,
                                        mu.pennation_deg, bb.length_m,
                                        sp.recoverable_extension_m + sp.pretension_extension_m)
        row[FREE_LEN] = free
        row[ANCHOR:ANCHOR + 18] = anchors.ravel()
        # Effects: neutral (see neck_env.effects for what switches them on).
        row[PAYLOAD_MG] = 0.0
        row[PAYLOAD_COM] = p.head.com_height_m
        row[VISCO_K], row[VISCO_TAU] = 0.0, 1.0
        row[FRICTION] = 0.0
        row[SUPPLY_V], row[WIRING_R] = np.inf, 0.0
        row[COUPLING] = 0.0
        row[CONV_GAIN], row[CONV_TCOEF] = 1.0, 0.0
        row[FATIGUE_RATE], row[FATIGUE_MAX] = 0.0, 0.0
        row[CUTOFF_C] = np.inf  # the physics has no cut; the envs and the rig set one
        row[TERM_G] = p.thermal.terminal_conductance_W_K
        row[TERM_C] = p.thermal.terminal_heat_capacity_J_K
        row[TERM_LOSS] = p.thermal.terminal_loss_W_K
        row[CONV_EXP] = p.thermal.convection_exponent
    refresh_derived(out)
    return out


def cooling_time_constant_s(params: NeckParams) -> float:
    """m c / (h A) of a spring, = rho c_p d / (4 h) for a wire: the time constant of a cooling
    tail, which cooling recordings pin whatever split of h and heat capacity a model uses."""
    c = constants_from_params(params)[0]
    return float(c[HEAT_CAP] / c[HA])


def cold_terminals_cooling_time_constant_s(params: NeckParams) -> float:
    """m c / (h A + G): the time constant a cooling tail starts with while the muscle's
    terminals are still at ambient (what a bench measurement of one tail gives)."""
    c = constants_from_params(params)[0]
    return float(c[HEAT_CAP] / (c[HA] + c[TERM_G]))


def refresh_derived(consts: np.ndarray) -> None:
    """Recompute the derived columns after base columns changed (randomization, fitting)."""
    consts[:, INV_C_A] = 1.0 / consts[:, C_A]
    consts[:, INV_C_M] = 1.0 / consts[:, C_M]
    consts[:, INV_BAND_A] = 1.0 / (consts[:, AF] - consts[:, AS])
    consts[:, INV_BAND_M] = 1.0 / (consts[:, MS] - consts[:, MF])
    consts[:, COS_PSI:COS_PSI + 3] = np.cos(consts[:, PSI:PSI + 3])
    consts[:, SIN_PSI:SIN_PSI + 3] = np.sin(consts[:, PSI:PSI + 3])


def initial_state(consts: np.ndarray, n_rigs: int | None = None) -> np.ndarray:
    """Upright neck at rest: springs at ambient, fully martensite, on the cooling branch."""
    n = consts.shape[0] if n_rigs is None else n_rigs
    if consts.shape[0] not in (1, n):
        raise ValueError(f"constants are for {consts.shape[0]} rigs, state asked for {n}")
    x = np.zeros((n, N_STATE))
    x[:, S_T:S_T + 3] = np.broadcast_to(consts[:, AMBIENT:AMBIENT + 1], (n, 3))
    x[:, S_TERM:S_TERM + 3] = x[:, S_T:S_T + 3]
    x[:, S_XI:S_XI + 3] = 1.0
    return x


@jit
def rig_scratch():
    """Scratch arrays of one ``advance_rig`` call: kinematics (tip (3,), its Jacobian (3, 3),
    head rotation (3, 3)), spring geometry (offsets, unit vectors, extensions), forces,
    generalized forces, muscle moments, currents and temperatures."""
    return (np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.empty((3, 2, 3)), np.empty((3, 2)), np.empty((3, 2)), np.empty(3),
            np.empty((3, 3)), np.empty(3), np.empty(3))


@jit
def over_temperature(temperature_C, cutoff_C):
    """The over-temperature rule: a muscle whose spring is at or above ``cutoff_C`` gets no
    current (as the rig firmware does with thermistors). Used by the plant and, through
    ``neck_env.task.Task``, by the rig env."""
    return temperature_C >= cutoff_C


@jit
def budget_energy_scale(energy_J, left_J):
    """The energy-budget rule: the factor on a step's planned electrical energy that keeps it
    within what is left -- 1 if it fits, else ``left / planned`` (0 once the budget is spent),
    so the budget is met exactly and never overdrawn. Currents scale by its square root."""
    if energy_J <= left_J:
        return 1.0
    return left_J / energy_J if energy_J > 0.0 else 0.0


@jit
def advance_rig(c, x, cur, dt, n_sub, budget, out, scratch):
    """Advance one rig (constants row ``c``, state row ``x``) by ``n_sub`` substeps of ``dt``
    with commanded currents ``cur`` (3,); fill its output row ``out``; return the energy budget
    left (J). ``scratch`` comes from ``rig_scratch()``: a caller looping over rigs allocates it
    once. This is the plant's one per-rig step: ``step_inplace`` and the env core both call it.
    """
    tip, dtip, rot, offset, unit, ext, forces, qf, fmus, amps, temps = scratch
    for k in range(3):
        out[O_ENERGY + k] = 0.0
        out[O_CURRENT + k] = 0.0
        out[O_CONV + k] = 0.0
    for _ in range(n_sub):
        bx, by, eps = x[S_Q], x[S_Q + 1], x[S_Q + 2]
        f1, f2 = kinematics(bx, by, c[LENGTH], tip, dtip, rot)
        spring_geometry(c, bx, by, eps, f1, f2, tip, offset, unit, ext)
        # Currents: commanded, cut above the safety temperature, limited by the supply's
        # compliance voltage, then by the budget.
        e_sub = 0.0
        for k in range(3):
            r = resistance(c, x[S_XI + k])
            a = 0.0 if over_temperature(x[S_T + k], c[CUTOFF_C]) else abs(cur[k])
            if c[SUPPLY_V] < np.inf:
                a = min(a, c[SUPPLY_V] / (SPRINGS_PER_MUSCLE * r + c[WIRING_R]))
            amps[k] = a
            e_sub += SPRINGS_PER_MUSCLE * a * a * r * dt
            temps[k] = x[S_T + k]
        if e_sub > budget:
            # Joule energy goes with I^2: the energy factor's root scales the currents.
            s = math.sqrt(budget_energy_scale(e_sub, budget))
            for k in range(3):
                amps[k] *= s
        budget = max(budget - min(e_sub, budget), 0.0)
        k_springs = 0.0
        # A terminal path adds its conductance to the air's and its excess temperature as a
        # heat source: the spring then relaxes exactly toward the mix of both sinks.
        hA = max(c[HA] * c[CONV_GAIN], 1e-9) + c[TERM_G]
        decay = math.exp(-dt * hA / c[HEAT_CAP])
        for k in range(3):
            coupling = 0.0
            for j in range(3):
                coupling += temps[j] - temps[k]
            if c[CONV_TCOEF] != 0.0 or c[CONV_EXP] != 0.0:
                excess = temps[k] - c[AMBIENT]
                h_rel = 1.0 + c[CONV_TCOEF] * excess
                if c[CONV_EXP] != 0.0:
                    h_rel *= (max(excess, CONV_MIN_DT_K) / CONV_REF_DT_K) ** c[CONV_EXP]
                hA = max(c[HA] * c[CONV_GAIN] * h_rel, 1e-9) + c[TERM_G]
                decay = math.exp(-dt * hA / c[HEAT_CAP])
            extra = c[COUPLING] * coupling + c[TERM_G] * (x[S_TERM + k] - c[AMBIENT])
            # Fatigue: the recoverable strain lost stays in the wire as permanent set (it
            # lengthens the spring's free length), so the cold spring pulls as before and the
            # hot one less; strain that vanished instead would shorten the cold spring.
            lost = x[S_FATIGUE + k]
            gamma_L = c[GAMMA_L] * (1.0 - lost)
            if lost > 0.0:
                set_ext = lost * c[GAMMA_L] / c[SHEAR_PER_EXT]
                ext[k, 0] -= set_ext
                ext[k, 1] -= set_ext
            xi_old = x[S_XI + k]
            T, xi, heating, scale, joule, conv = phase_thermal_step(
                c, temps[k], xi_old, x[S_HEAT + k] > 0.5, x[S_SCALE + k], amps[k],
                0.5 * (ext[k, 0] + ext[k, 1]), dt, extra, hA, decay, gamma_L)
            x[S_T + k] = T
            if c[TERM_G] > 0.0:
                # the terminals relax toward the mix of their springs and the air (exact for
                # the springs held at their new temperature over the step)
                g_all = SPRINGS_PER_MUSCLE * c[TERM_G] + c[TERM_LOSS]
                t_eq = (SPRINGS_PER_MUSCLE * c[TERM_G] * T + c[TERM_LOSS] * c[AMBIENT]) / g_all
                x[S_TERM + k] = t_eq + (x[S_TERM + k] - t_eq) * math.exp(-dt * g_all / c[TERM_C])
            x[S_XI + k] = xi
            x[S_HEAT + k] = 1.0 if heating else 0.0
            x[S_SCALE + k] = scale
            if c[FATIGUE_RATE] > 0.0:
                x[S_FATIGUE + k] = min(c[FATIGUE_MAX], x[S_FATIGUE + k] + c[FATIGUE_RATE] * abs(xi - xi_old))
            out[O_ENERGY + k] += SPRINGS_PER_MUSCLE * joule
            out[O_CONV + k] += SPRINGS_PER_MUSCLE * conv
            out[O_CURRENT + k] += amps[k] / n_sub
            for s in range(SPRINGS_PER_MUSCLE):
                forces[k, s] = spring_force(c, ext[k, s], xi, T, gamma_L)
                if forces[k, s] > 0.0:
                    k_springs += spring_rate(c, xi)
        generalized_forces(forces, unit, offset, dtip, rot, qf, fmus)
        if c[PAYLOAD_MG] > 0.0:
            # Gravity on the head's centre of mass at p(l) + h R_b z: Q_i = -m g dz_com/dq_i.
            h = c[PAYLOAD_COM]
            for i in range(3):
                dz = dtip[i, 2] + h * (rot[i, 0] * rot[2, 1] - rot[i, 1] * rot[2, 0])
                qf[i] -= c[PAYLOAD_MG] * dz
        k_musc = k_springs * c[LEVER_SQ]
        for i in range(3):
            k_i = c[K_BEND] if i < 2 else c[K_TWIST]
            qf[i] -= k_i * x[S_Q + i] + x[S_VISCO + i]
        if c[FRICTION] > 0.0:
            # Coulomb friction with stiction on bending: no motion until the net moment beats it.
            mag = math.sqrt(qf[0] * qf[0] + qf[1] * qf[1])
            keep = 0.0 if mag <= c[FRICTION] else 1.0 - c[FRICTION] / mag
            qf[0] *= keep
            qf[1] *= keep
        k_bend = c[K_BEND] + c[VISCO_K] + k_musc
        k_twist = c[K_TWIST] + c[VISCO_K] + k_musc
        gain_bend = (1.0 - math.exp(-dt * k_bend / c[DAMPING])) / k_bend
        gain_twist = (1.0 - math.exp(-dt * k_twist / c[DAMPING])) / k_twist
        for i in range(3):
            dq = (gain_bend if i < 2 else gain_twist) * qf[i]
            x[S_Q + i] += dq
            if c[VISCO_K] > 0.0:
                # Maxwell branch of the standard linear solid, exact for constant q_dot.
                decay = math.exp(-dt / c[VISCO_TAU])
                x[S_VISCO + i] = (x[S_VISCO + i] * decay
                                  + c[VISCO_K] * dq / dt * c[VISCO_TAU] * (1.0 - decay))
    bx, by = x[S_Q], x[S_Q + 1]
    out[O_THETA] = math.degrees(math.sqrt(bx * bx + by * by))
    phi = math.degrees(math.atan2(by, bx)) % 360.0
    out[O_PHI] = phi if phi < 360.0 else 0.0
    for k in range(3):
        out[O_POWER + k] = out[O_ENERGY + k] / (n_sub * dt)
        out[O_CONV + k] /= n_sub * dt
        out[O_FORCE + k] = math.sqrt(fmus[k, 0] ** 2 + fmus[k, 1] ** 2 + fmus[k, 2] ** 2)
    return budget


@jit
def _advance_range(consts, state, cur, dt, n_sub, budget, out, start, stop):
    scratch = rig_scratch()
    shared = consts.shape[0] == 1
    for i in range(start, stop):
        c = consts[0] if shared else consts[i]
        budget[i] = advance_rig(c, state[i], cur[i], dt, n_sub, budget[i], out[i], scratch)


@jit
def _step_serial(consts, state, cur, dt, n_sub, budget, out):
    _advance_range(consts, state, cur, dt, n_sub, budget, out, 0, state.shape[0])


@jit(parallel=True)
def _step_parallel(consts, state, cur, dt, n_sub, budget, out):
    n = state.shape[0]
    n_chunks = (n + PARALLEL_CHUNK - 1) // PARALLEL_CHUNK
    for ch in prange(n_chunks):
        _advance_range(consts, state, cur, dt, n_sub, budget, out, ch * PARALLEL_CHUNK,
                       min(n, (ch + 1) * PARALLEL_CHUNK))


def step_inplace(consts: np.ndarray, state: np.ndarray, currents_A: np.ndarray, dt_s: float,
                 n_substeps: int, energy_left_J: np.ndarray, out: np.ndarray) -> None:
    """Advance ``state`` (N, N_STATE) in place by ``n_substeps`` x ``dt_s``; fill ``out``.

    No validation (the caller owns it): float64 C-contiguous arrays, ``currents_A`` (N, 3)
    finite, ``energy_left_J`` (N,) debited in place, ``consts`` (1 or N, N_CONST).
    """
    fn = _step_parallel if state.shape[0] >= PARALLEL_FROM else _step_serial
    fn(consts, state, currents_A, dt_s, n_substeps, energy_left_J, out)


def check_currents(current_A, n_rigs: int) -> np.ndarray:
    """Validate currents: finite, shape (N, 3). Sign is irrelevant to Joule heating."""
    cur = np.asarray(current_A, dtype=float)
    if cur.shape != (n_rigs, 3):
        raise ValueError(f"currents must have shape ({n_rigs}, 3), got {cur.shape}")
    if not np.all(np.isfinite(cur)):
        raise ValueError(f"currents must be finite, got {cur[~np.isfinite(cur)][:3]}")
    return np.ascontiguousarray(cur)


def step(consts: np.ndarray, state: np.ndarray, currents_A, dt_s: float, n_substeps: int = 1,
         energy_left_J: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pure step: returns (new state, outputs (N, N_OUT), energy left (N,))."""
    state = np.array(state, dtype=float, order="C")
    n = state.shape[0]
    if state.ndim != 2 or state.shape[1] != N_STATE:
        raise ValueError(f"state must have shape (N, {N_STATE}), got {state.shape}")
    if consts.ndim != 2 or consts.shape[1] != N_CONST or consts.shape[0] not in (1, n):
        raise ValueError(f"constants must have shape (1 or {n}, {N_CONST}), got {consts.shape}")
    if not (dt_s > 0 and math.isfinite(dt_s)) or n_substeps < 1:
        raise ValueError(f"need dt_s > 0 and n_substeps >= 1, got {dt_s}, {n_substeps}")
    cur = check_currents(currents_A, n)
    left = (np.full(n, np.inf) if energy_left_J is None
            else np.array(np.broadcast_to(energy_left_J, (n,)), dtype=float))
    out = np.empty((n, N_OUT))
    step_inplace(np.ascontiguousarray(consts, dtype=float), state, cur, float(dt_s),
                 int(n_substeps), left, out)
    return state, out, left


class Trajectory(NamedTuple):
    """Time series of a batched simulation; leading axis is time (steps), then rigs."""

    t_s: np.ndarray  # (S,)
    theta_deg: np.ndarray  # (S, N)
    phi_deg: np.ndarray  # (S, N)
    T_C: np.ndarray  # (S, N, 3)
    xi: np.ndarray  # (S, N, 3)
    power_W: np.ndarray  # (S, N, 3)
    muscle_force_N: np.ndarray  # (S, N, 3)
    current_A: np.ndarray  # (S, N, 3): what flowed (after supply limit / budget)
    q: np.ndarray  # (S, N, 3)


def simulate(consts: np.ndarray, currents_A: np.ndarray, dt_s: float = EXPERIMENT_DT_S,
             state: np.ndarray | None = None) -> tuple[Trajectory, np.ndarray]:
    """Run currents (S, N, 3), one row per step of ``dt_s``; returns the trajectory after each
    step (t = dt, 2 dt, ...) and the final state."""
    currents_A = np.asarray(currents_A, float)
    if currents_A.ndim != 3 or currents_A.shape[2] != 3:
        raise ValueError(f"currents_A must have shape (steps, rigs, 3), got {currents_A.shape}")
    if not np.all(np.isfinite(currents_A)):
        raise ValueError("currents_A must be finite")
    n_steps, n = currents_A.shape[:2]
    x = initial_state(consts, n) if state is None else np.array(state, dtype=float, order="C")
    consts = np.ascontiguousarray(consts, dtype=float)
    left = np.full(n, np.inf)
    out = np.empty((n, N_OUT))
    rec_out = np.empty((n_steps, n, N_OUT))
    rec_x = np.empty((n_steps, n, N_STATE))
    for k in range(n_steps):
        step_inplace(consts, x, np.ascontiguousarray(currents_A[k]), dt_s, 1, left, out)
        rec_out[k] = out
        rec_x[k] = x
    traj = Trajectory(
        t_s=dt_s * np.arange(1, n_steps + 1),
        theta_deg=rec_out[:, :, O_THETA],
        phi_deg=rec_out[:, :, O_PHI],
        T_C=rec_x[:, :, S_T:S_T + 3],
        xi=rec_x[:, :, S_XI:S_XI + 3],
        power_W=rec_out[:, :, O_POWER:O_POWER + 3],
        muscle_force_N=rec_out[:, :, O_FORCE:O_FORCE + 3],
        current_A=rec_out[:, :, O_CURRENT:O_CURRENT + 3],
        q=rec_x[:, :, S_Q:S_Q + 3],
    )
    return traj, x


def pulse_currents(current_A: Sequence[float] | np.ndarray, muscle: int, on_s: float,
                   total_s: float, dt_s: float = EXPERIMENT_DT_S) -> np.ndarray:
    """Currents (S, N, 3) for the paper's step experiment: muscle ``muscle`` (0-based) driven at
    ``current_A[n]`` for ``on_s`` seconds from t = 0, then off until ``total_s``."""
    amps = np.atleast_1d(np.asarray(current_A, float))
    steps = int(round(total_s / dt_s))
    on = (np.arange(steps) * dt_s) < on_s - 1e-9
    cur = np.zeros((steps, amps.size, 3))
    cur[:, :, muscle] = on[:, None] * amps[None, :]
    return cur


def pose_angles_deg(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) in degrees from a state array (N, N_STATE)."""
    theta, phi = bend_angles(state[:, S_Q:S_Q + 3])
    return np.rad2deg(theta), np.rad2deg(phi)
