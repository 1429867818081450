"""Physics checks against hand-derived numbers, conservation laws and limit cases."""

import math

import numpy as np
import pytest

from neck_env.params import NeckParams, default_params
from neck_env.physics import sma
from neck_env.physics.backbone import head_rotation, kinematics, pose_from_angles
from neck_env.physics.muscles import generalized_forces, spring_geometry
from neck_env.physics.plant import PlantConstants, initial_state, pulse_currents, simulate, step


@pytest.fixture(scope="module")
def params():
    return default_params()


@pytest.fixture(scope="module")
def pc(params):
    return PlantConstants.from_params(params)


# --- SMA spring -----------------------------------------------------------------------------

def test_spring_rate_limits_match_closed_form():
    # Hand numbers for the datasheet spring: d = 0.8 mm, D = 5 mm, n = 14, nu = 0.33.
    # G_a = 75 GPa / 2.66 = 28.195 GPa; d^4 / (8 n D^3) = 4.096e-13 / 1.4e-5 = 2.9257e-8 m.
    # k_a = 824.9 N/m; G_m = 28 GPa / 2.66 = 10.526 GPa -> k_m = 307.96 N/m.
    p = NeckParams()
    c = PlantConstants.from_params(p).sma
    k = sma.spring_rate(c, np.array([[0.0, 1.0]]))
    assert k[0, 0] == pytest.approx(824.9, rel=1e-3)
    assert k[0, 1] == pytest.approx(307.96, rel=1e-3)
    # The force law has exactly that slope at fixed phase (finite difference, taut spring).
    T = np.full((1, 2), 25.0)
    xi = np.array([[0.0, 1.0]])
    ext = np.full((1, 2), 0.05)
    slope = (sma.spring_force(c, ext + 1e-6, xi, T) - sma.spring_force(c, ext, xi, T)) / 1e-6
    np.testing.assert_allclose(slope, k, rtol=1e-6)


def test_spring_carries_tension_only(pc):
    c = pc.sma
    T = np.full((1, 3), 25.0)
    xi = np.ones((1, 3))
    # Martensite spring shorter than its recoverable extension is slack: no push.
    f = sma.spring_force(c, np.array([[-0.01, 0.0, 0.005]]), xi, T)
    np.testing.assert_array_equal(f, 0.0)


def test_resistance_is_phase_weighted(pc):
    c = pc.sma
    r = sma.resistance(c, np.array([[1.0, 0.0, 0.25]]))
    assert r[0, 0] == pytest.approx(c.R_martensite_ohm[0, 0])
    assert r[0, 1] == pytest.approx(c.R_austenite_ohm[0, 0])
    assert r[0, 2] == pytest.approx(0.25 * c.R_martensite_ohm[0, 0] + 0.75 * c.R_austenite_ohm[0, 0])


def _cycling_run(pc, dt):
    # Reversals mid-transformation: 7 A on/off at 3 s / 2 s, several times, then cool.
    t = np.arange(int(round(30 / dt))) * dt
    on = ((t % 5.0) < 3.0) & (t < 20.0)
    cur = np.zeros((t.size, 1, 3))
    cur[:, 0, 0] = 7.0 * on
    tr, _ = simulate(pc, cur, dt)
    return tr


def test_phase_fraction_bounded_and_continuous_through_reversals(pc):
    tr1 = _cycling_run(pc, 0.01)
    tr2 = _cycling_run(pc, 0.005)
    xi = tr1.xi[:, 0, 0]
    assert xi.min() >= 0.0 and xi.max() <= 1.0
    assert xi.min() < 0.8, "the cycle must reach into the transformation band"
    # Reversals inside the band happened (xi neither 0 nor 1 when the current switched).
    T = tr1.T_C[:, 0, 0]
    dT = np.diff(T)
    rev = np.nonzero(np.sign(dT[1:]) != np.sign(dT[:-1]))[0]
    assert np.any((xi[rev] > 0.05) & (xi[rev] < 0.95))
    # Continuity: the largest one-step change shrinks with the step (no jump at reversals).
    j1 = np.abs(np.diff(tr1.xi[:, 0, 0])).max()
    j2 = np.abs(np.diff(tr2.xi[:, 0, 0])).max()
    assert j1 < 0.02
    assert j2 < 0.7 * j1


def test_minor_loop_holds_xi_after_reversal(pc):
    # Heat into the band, then cut the current: on the cooling branch xi must not jump back to
    # the paper's full-amplitude branch; it holds until T falls below M_s'.
    tr, _ = simulate(pc, pulse_currents([7.0], 0, 4.0, 8.0))
    k_off = int(round(4.0 / 0.01))
    xi_off = tr.xi[k_off - 1, 0, 0]
    assert 0.05 < xi_off < 0.95
    np.testing.assert_allclose(tr.xi[k_off:k_off + 50, 0, 0], xi_off, atol=1e-9)


def test_hysteresis_cooling_branch_lags_heating(pc):
    tr, _ = simulate(pc, pulse_currents([8.0], 0, 5.0, 60.0))
    T, xi = tr.T_C[:, 0, 0], tr.xi[:, 0, 0]
    k_peak = int(np.argmax(T))
    for T_probe in (80.0, 70.0):
        i_heat = np.argmax(T[:k_peak] >= T_probe)
        i_cool = k_peak + np.argmax(T[k_peak:] <= T_probe)
        assert xi[i_cool] < xi[i_heat], f"at {T_probe} C cooling holds more austenite than heating"


def test_energy_balance_over_a_pulse(pc):
    dt = 0.01
    cur = pulse_currents([7.0], 0, 5.0, 15.0, dt)
    st = initial_state(pc, 1)
    joule, Ts, xis = [], [st.phase.T_C[0, 0]], [1.0]
    for k in range(cur.shape[0]):
        st, out = step(pc, st, cur[k], dt)
        joule.append(out.power_W[0, 0] / 2 * dt)  # one spring
        Ts.append(st.phase.T_C[0, 0])
        xis.append(st.phase.xi[0, 0])
    Ts, xis = np.array(Ts), np.array(xis)
    c = pc.sma
    heat_in = np.sum(joule)
    stored = c.heat_capacity_J_K[0, 0] * (Ts[-1] - Ts[0])
    convected = c.hA_W_K[0, 0] * np.trapezoid(Ts - c.ambient_C[0, 0], dx=dt)
    latent = -c.latent_J[0, 0] * (xis[-1] - xis[0])  # absorbed by M -> A
    assert xis[-1] < 0.9, "the pulse must transform so latent heat is tested"
    assert stored + convected + latent == pytest.approx(heat_in, rel=0.01)


# --- Backbone kinematics --------------------------------------------------------------------

def test_tip_position_matches_eq6():
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.05, 1.2, 20)
    phi = rng.uniform(0, 2 * np.pi, 20)
    l = 0.1
    kin = kinematics(pose_from_angles(theta, phi), l)
    kappa = theta / l
    expect = np.stack([np.cos(phi) / kappa * (1 - np.cos(kappa * l)),
                       np.sin(phi) / kappa * (1 - np.cos(kappa * l)),
                       np.sin(kappa * l) / kappa], -1)
    np.testing.assert_allclose(kin.tip_m, expect, rtol=1e-12, atol=1e-15)
    # Upright limit is smooth: p(l) = (0, 0, l).
    np.testing.assert_allclose(kinematics(np.zeros((1, 3)), l).tip_m, [[0, 0, l]], atol=1e-15)


def _rz(a):
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _ry(a):
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def test_head_rotation_matches_eq7():
    theta, phi, eps = 0.4, 2.1, 0.05
    R = head_rotation(pose_from_angles([theta], [phi], [eps]))[0]
    np.testing.assert_allclose(R, _rz(phi) @ _ry(theta) @ _rz(eps - phi), atol=1e-12)


@pytest.mark.parametrize("q", [[0.3, -0.2, 0.05], [1e-4, 2e-4, 0.0], [0.0, 0.0, 0.0]])
def test_jacobians_match_finite_differences(q):
    q = np.array([q])
    l = 0.1
    kin = kinematics(q, l)
    R0 = head_rotation(q)[0]
    h = 1e-7
    for i in range(3):
        dq = np.zeros((1, 3))
        dq[0, i] = h
        kp, km = kinematics(q + dq, l), kinematics(q - dq, l)
        np.testing.assert_allclose((kp.tip_m - km.tip_m)[0] / (2 * h), kin.dtip_dq[0, i], atol=1e-7)
        W = (head_rotation(q + dq)[0] - head_rotation(q - dq)[0]) / (2 * h) @ R0.T
        axis = np.array([W[2, 1], W[0, 2], W[1, 0]])
        np.testing.assert_allclose(axis, kin.rot_axis_dq[0, i], atol=1e-6)


def test_generalized_forces_equal_virtual_work(pc):
    # Q = -sum_f F_f dL_f/dq for fixed spring tensions (eq. 11 moment balance by virtual work).
    q = np.array([[0.25, 0.1, 0.02]])
    tension = np.array([[[3.0, 2.0], [1.0, 4.0], [0.5, 0.0]]])
    kin = kinematics(q, pc.length_m)
    Q, _ = generalized_forces(kin, spring_geometry(pc.muscles, kin, q[:, 2]), tension)
    h = 1e-7
    for i in range(3):
        dq = np.zeros((1, 3))
        dq[0, i] = h
        Lp = spring_geometry(pc.muscles, kinematics(q + dq, pc.length_m), (q + dq)[:, 2]).spring_length_m
        Lm = spring_geometry(pc.muscles, kinematics(q - dq, pc.length_m), (q - dq)[:, 2]).spring_length_m
        assert Q[0, i] == pytest.approx(-np.sum(tension * (Lp - Lm) / (2 * h)), rel=1e-6, abs=1e-9)


def test_pennate_force_is_2Ff_cos_alpha(pc, params):
    # Upright pose, equal spring tensions: the tendon force is 2 F_f cos(alpha) (eq. 12).
    q = np.zeros((1, 3))
    kin = kinematics(q, pc.length_m)
    geo = spring_geometry(pc.muscles, kin, q[:, 2])
    _, f_muscle = generalized_forces(kin, geo, np.full((1, 3, 2), 5.0))
    alpha = math.radians(params.muscles.pennation_deg)
    np.testing.assert_allclose(np.linalg.norm(f_muscle, axis=-1), 2 * 5.0 * math.cos(alpha), rtol=1e-12)


# --- Whole plant ----------------------------------------------------------------------------

def test_zero_current_leaves_neck_upright(pc):
    tr, st = simulate(pc, np.zeros((2000, 2, 3)))
    assert np.abs(tr.theta_deg).max() < 1e-9
    np.testing.assert_allclose(tr.T_C, 25.0, atol=1e-9)
    np.testing.assert_array_equal(tr.xi, 1.0)


def test_symmetry_between_muscles(pc):
    cur = pulse_currents([6.5], 0, 5.0, 10.0)
    tr1, _ = simulate(pc, cur)
    tr2, _ = simulate(pc, np.roll(cur, 1, axis=2))  # the same current on muscle 2
    tr3, _ = simulate(pc, np.roll(cur, 2, axis=2))  # ... on muscle 3
    np.testing.assert_allclose(tr2.theta_deg, tr1.theta_deg, atol=1e-9)
    np.testing.assert_allclose(tr3.theta_deg, tr1.theta_deg, atol=1e-9)
    bent = tr1.theta_deg[:, 0] > 1.0
    dphi2 = (tr2.phi_deg[bent, 0] - tr1.phi_deg[bent, 0] + 180) % 360 - 180
    dphi3 = (tr3.phi_deg[bent, 0] - tr1.phi_deg[bent, 0] + 180) % 360 - 180
    np.testing.assert_allclose(dphi2, -120.0, atol=1e-6)  # 180 -> 60
    np.testing.assert_allclose(dphi3, 120.0, atol=1e-6)  # 180 -> 300
    np.testing.assert_allclose(tr1.phi_deg[bent, 0], 180.0, atol=1e-6)


def test_bends_toward_driven_muscle_and_returns_when_cool(pc):
    tr, _ = simulate(pc, pulse_currents([7.0], 1, 5.0, 90.0))
    assert tr.theta_deg[:, 0].max() > 10.0
    assert tr.theta_deg[-1, 0] < 0.5
    assert tr.T_C[-1, 0, 1] < 30.0


def test_step_convergence(pc):
    """Halving the physics step (0.01 s -> 0.005 s) changes theta(t) by < 0.15 deg."""
    results = {}
    for dt in (0.01, 0.005):
        tr, _ = simulate(pc, pulse_currents([5.0, 6.0, 7.0, 8.0], 0, 5.0, 30.0, dt), dt)
        results[dt] = tr
    ts = np.arange(0.01, 30.0 + 1e-9, 0.01)
    a = results[0.01].theta_deg[np.round(ts / 0.01).astype(int) - 1]
    b = results[0.005].theta_deg[np.round(ts / 0.005).astype(int) - 1]
    assert np.abs(a - b).max() < 0.15
    assert a.max() > 20.0


def test_batched_rigs_with_different_parameters_match_single_runs(params):
    other = params.replace(thermal__convection_W_m2K=150.0, backbone__bending_stiffness_Nm2=0.08)
    cur = pulse_currents([7.0, 7.0], 0, 5.0, 8.0)
    tr, _ = simulate(PlantConstants.from_params([params, other]), cur)
    tr_a, _ = simulate(PlantConstants.from_params(params), cur[:, :1])
    tr_b, _ = simulate(PlantConstants.from_params(other), cur[:, 1:])
    np.testing.assert_allclose(tr.theta_deg[:, 0], tr_a.theta_deg[:, 0], atol=1e-12)
    np.testing.assert_allclose(tr.theta_deg[:, 1], tr_b.theta_deg[:, 0], atol=1e-12)
    assert abs(tr_a.theta_deg[-1, 0] - tr_b.theta_deg[-1, 0]) > 1.0


# --- Bad input ------------------------------------------------------------------------------

def test_non_finite_or_misshaped_currents_raise(pc):
    st = initial_state(pc, 2)
    with pytest.raises(ValueError, match="finite"):
        step(pc, st, np.array([[1.0, np.nan, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    with pytest.raises(ValueError, match="finite"):
        step(pc, st, np.array([[np.inf, 0.0, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        step(pc, st, np.zeros((2, 2)), 0.01)
