"""Physics checks against hand-derived numbers, conservation laws and limit cases."""

import math

import numpy as np
import pytest

from neck_env.params import NeckParams, default_params
from neck_env.physics import layout as L
from neck_env.physics.backbone import head_rotation, kinematics, kinematics_batch, pose_from_angles
from neck_env.physics.muscles import generalized_forces, spring_geometry
from neck_env.physics.plant import (constants_from_params, cooling_time_constant_s, initial_state,
                                    pulse_currents, simulate, step)
from neck_env.physics.sma import resistance_batch, spring_force_batch, spring_rate_batch


@pytest.fixture(scope="module")
def params():
    return default_params()


@pytest.fixture(scope="module")
def pc(params):
    return constants_from_params(params)


# --- SMA spring -----------------------------------------------------------------------------

def test_spring_rate_limits_match_closed_form():
    # Hand numbers for the datasheet spring: d = 0.8 mm, D = 5 mm, n = 14, nu = 0.33.
    # G_a = 75 GPa / 2.66 = 28.195 GPa; d^4 / (8 n D^3) = 4.096e-13 / 1.4e-5 = 2.9257e-8 m.
    # k_a = 824.9 N/m; G_m = 28 GPa / 2.66 = 10.526 GPa -> k_m = 307.96 N/m.
    c = constants_from_params(NeckParams())
    k = spring_rate_batch(c, np.array([[0.0, 1.0]]))
    assert k[0, 0] == pytest.approx(824.9, rel=1e-3)
    assert k[0, 1] == pytest.approx(307.96, rel=1e-3)
    # The force law has exactly that slope at fixed phase (finite difference, taut spring).
    T = np.full((1, 2), 25.0)
    xi = np.array([[0.0, 1.0]])
    ext = np.full((1, 2), 0.05)
    slope = (spring_force_batch(c, ext + 1e-6, xi, T) - spring_force_batch(c, ext, xi, T)) / 1e-6
    np.testing.assert_allclose(slope, k, rtol=1e-6)


def test_spring_carries_tension_only(pc):
    T = np.full((1, 3), 25.0)
    xi = np.ones((1, 3))
    # Martensite spring shorter than its recoverable extension is slack: no push.
    f = spring_force_batch(pc, np.array([[-0.01, 0.0, 0.005]]), xi, T)
    np.testing.assert_array_equal(f, 0.0)


def test_resistance_is_phase_weighted(pc):
    r = resistance_batch(pc, np.array([[1.0, 0.0, 0.25]]))
    rm, ra = pc[0, L.R_M], pc[0, L.R_A]
    # Hand numbers: 76 / 82 uOhm cm over pi * 5 mm * 14 turns of 0.8 mm wire = 0.3325 / 0.3588 ohm.
    assert rm == pytest.approx(0.3325, rel=1e-3)
    assert ra == pytest.approx(0.3588, rel=1e-3)
    np.testing.assert_allclose(r[0], [rm, ra, 0.25 * rm + 0.75 * ra], rtol=1e-12)


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
    x = initial_state(pc, 1)
    joule, Ts, xis = [], [x[0, L.S_T]], [1.0]
    for k in range(cur.shape[0]):
        x, out, _ = step(pc, x, cur[k], dt)
        joule.append(out[0, L.O_ENERGY] / 2)  # one spring of the pair
        Ts.append(x[0, L.S_T])
        xis.append(x[0, L.S_XI])
    Ts, xis = np.array(Ts), np.array(xis)
    heat_in = np.sum(joule)
    stored = pc[0, L.HEAT_CAP] * (Ts[-1] - Ts[0])
    convected = pc[0, L.HA] * np.trapezoid(Ts - pc[0, L.AMBIENT], dx=dt)
    latent = -pc[0, L.LATENT_J] * (xis[-1] - xis[0])  # absorbed by M -> A
    assert xis[-1] < 0.9, "the pulse must transform so latent heat is tested"
    assert stored + convected + latent == pytest.approx(heat_in, rel=0.01)
    # Hand check of the first step: I^2 R_m dt at 7 A through one martensite spring.
    assert joule[0] == pytest.approx(49 * pc[0, L.R_M] * dt, rel=1e-12)


def test_cooling_tail_decays_with_the_wire_time_constant(params, pc):
    # m c / (h A) of a wire is rho c_p d / (4 h), whatever its length
    tau = cooling_time_constant_s(params)
    sp, mat = params.spring, params.material
    assert tau == pytest.approx(mat.density_kg_m3 * mat.specific_heat_J_kgK * sp.wire_diameter_m
                                / (4 * params.thermal.convection_W_m2K), rel=1e-12)
    # a simulated cooling tail: while no phase changes (no latent heat), T - ambient decays as
    # exp(-t / tau)
    tr, _ = simulate(pc, pulse_currents([8.0], 0, 5.0, 40.0))
    t, T, xi = tr.t_s, tr.T_C[:, 0, 0], tr.xi[:, 0, 0]
    cool = (t > 5.2) & (np.abs(np.gradient(xi, t)) < 1e-9) & (T - params.thermal.ambient_C > 5)
    assert cool.sum() > 20, "the tail must hold a stretch without transformation"
    slope = np.polyfit(t[cool], np.log(T[cool] - params.thermal.ambient_C), 1)[0]
    assert -1 / slope == pytest.approx(tau, rel=0.02)


@pytest.mark.parametrize("n", [0.15, 0.25])
def test_still_air_cools_a_spring_as_a_power_of_its_excess_temperature(params, n):
    # free convection: h ~ dT^n about 50 K (``layout.CONV_REF_DT_K``), so without a phase
    # change a tail's rate -d ln(dT)/dt is h A / (m c) at 50 K times (dT / 50 K)^n: 4^n faster
    # at 100 than at 25 K above ambient, where a constant h keeps it. The reverse
    # transformation is moved below ambient (even under the springs' stress), so none latent
    # heat enters the tail
    p0 = params.replace(material__Ms_C=-60.0, material__Mf_C=-70.0)
    amb = p0.thermal.ambient_C
    tau = cooling_time_constant_s(p0)

    def rates(p):
        tr, _ = simulate(constants_from_params(p), pulse_currents([8.0], 0, 6.0, 60.0))
        t, dT, xi = tr.t_s, tr.T_C[:, 0, 0] - amb, tr.xi[:, 0, 0]
        cooling = t > 6.2
        assert np.all(xi[cooling] == 0.0), "the tail must stay austenite"
        lam = -np.gradient(np.log(dT), t)
        return {x: lam[np.flatnonzero(cooling & (dT < x))[0]] for x in (100.0, 50.0, 25.0)}

    flat, still = rates(p0), rates(p0.replace(thermal__convection_exponent=n))
    assert flat[100.0] * tau == pytest.approx(1.0, rel=0.02)  # a constant h: m c / (h A)
    assert still[100.0] / still[25.0] == pytest.approx(4 ** n, rel=0.02)
    assert still[50.0] * tau == pytest.approx(1.0, rel=0.02)  # the calibrated h at 50 K
    with pytest.raises(ValueError, match="convection_exponent"):
        params.replace(thermal__convection_exponent=-0.1)


def _terminal_run(params, amps, seconds, dt=0.01):
    c = constants_from_params(params)
    x = initial_state(c, 1)
    cur = np.zeros((int(round(seconds / dt)), 1, 3))
    cur[:, 0, 0] = amps
    rows = []
    for k in range(cur.shape[0]):
        x, out, _ = step(c, x, cur[k], dt)
        rows.append((out[0, L.O_ENERGY], x[0, L.S_T], x[0, L.S_TERM], x[0, L.S_XI]))
    return c, np.array(rows)


def test_terminals_settle_where_the_two_heat_paths_balance(params):
    # constant power P into a spring: P = hA dT_w + G (dT_w - dT_t) and 2 G (dT_w - dT_t) =
    # L dT_t, so dT_w = P / (hA + G L / (2 G + L)) and dT_t = 2 G dT_w / (2 G + L)
    G, Lt = 0.02, 0.01
    p = params.replace(thermal__terminal_conductance_W_K=G, thermal__terminal_loss_W_K=Lt,
                       thermal__terminal_heat_capacity_J_K=0.2)  # settles within seconds
    c, rows = _terminal_run(p, 2.0, 300.0)  # stays martensite: no latent heat, fixed R
    assert np.all(rows[:, 3] == 1.0)
    P = rows[-1, 0] / 0.01 / 2  # W into one spring over the last step
    amb = p.thermal.ambient_C
    dTw = P / (c[0, L.HA] + G * Lt / (2 * G + Lt))
    assert rows[-1, 1] - amb == pytest.approx(dTw, rel=1e-3)
    assert rows[-1, 2] - amb == pytest.approx(2 * G / (2 * G + Lt) * dTw, rel=1e-3)
    # and the spring runs cooler than without the path, by the conductance it adds
    _, bare = _terminal_run(params, 2.0, 300.0)
    assert rows[-1, 1] < bare[-1, 1] - 1.0


def test_terminals_balance_the_energy_of_a_pulse(params):
    dt = 0.01
    p = params.replace(thermal__terminal_conductance_W_K=0.015, thermal__terminal_loss_W_K=0.012,
                       thermal__terminal_heat_capacity_J_K=1.5)
    c, rows = _terminal_run(p, np.r_[np.full(500, 7.0), np.zeros(2500)], 30.0, dt)
    amb = p.thermal.ambient_C
    Tw = np.r_[amb, rows[:, 1]]
    Tt = np.r_[amb, rows[:, 2]]
    xi = np.r_[1.0, rows[:, 3]]
    heat_in = rows[:, 0].sum()  # both springs
    springs = 2 * (c[0, L.HEAT_CAP] * (Tw[-1] - Tw[0]) + c[0, L.HA] * np.trapezoid(Tw - amb, dx=dt)
                   - c[0, L.LATENT_J] * (xi[-1] - xi[0]))
    terminals = c[0, L.TERM_C] * (Tt[-1] - Tt[0]) + c[0, L.TERM_LOSS] * np.trapezoid(Tt - amb, dx=dt)
    assert xi[1:].min() < 0.9, "the pulse must transform so latent heat is in the balance"
    assert Tt.max() - amb > 3.0, "the terminals must take a share worth testing"
    assert springs + terminals == pytest.approx(heat_in, rel=0.01)


def test_no_terminal_conductance_is_the_model_without_terminals(params):
    # with G = 0 neither the terminals' heat capacity nor their loss may reach the springs
    _, bare = _terminal_run(params, np.r_[np.full(500, 7.0), np.zeros(1000)], 15.0)
    _, other = _terminal_run(params.replace(thermal__terminal_heat_capacity_J_K=0.01,
                                            thermal__terminal_loss_W_K=5.0),
                             np.r_[np.full(500, 7.0), np.zeros(1000)], 15.0)
    assert np.array_equal(bare, other)
    assert np.all(bare[:, 2] == params.thermal.ambient_C)


def test_a_source_edit_drops_the_packages_stale_compiled_caches(tmp_path, monkeypatch):
    # numba checks a cached function against its own file only; the env's cached step inlines
    # the plant from another file, so any edit of the package must drop every cache
    from neck_env.physics import compile as C

    pkg = tmp_path / "pkg"
    (pkg / "physics" / "__pycache__").mkdir(parents=True)
    (pkg / "envs" / "__pycache__").mkdir(parents=True)
    (pkg / "physics" / "plant.py").write_text("A = 1\n")
    stale = pkg / "envs" / "__pycache__" / "core._rows-1.py311.nbi"
    stale.write_text("index")
    monkeypatch.setattr(C, "_PACKAGE", pkg)
    monkeypatch.setattr(C, "_STAMP", pkg / "physics" / "__pycache__" / "neck_env_sources.sha1")
    C._drop_stale_caches()  # no stamp yet: whatever is cached may predate these sources
    assert not stale.exists()
    fresh = pkg / "envs" / "__pycache__" / "core._rows-1.py311.nbc"
    fresh.write_text("code")
    C._drop_stale_caches()  # nothing edited: the cache stays
    assert fresh.exists()
    (pkg / "physics" / "plant.py").write_text("A = 2\n")
    C._drop_stale_caches()
    assert not fresh.exists()


# --- Backbone kinematics --------------------------------------------------------------------

def test_tip_position_matches_eq6():
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.05, 1.2, 20)
    phi = rng.uniform(0, 2 * np.pi, 20)
    l = 0.1
    tip, _, _ = kinematics_batch(pose_from_angles(theta, phi), l)
    kappa = theta / l
    expect = np.stack([np.cos(phi) / kappa * (1 - np.cos(kappa * l)),
                       np.sin(phi) / kappa * (1 - np.cos(kappa * l)),
                       np.sin(kappa * l) / kappa], -1)
    np.testing.assert_allclose(tip, expect, rtol=1e-12, atol=1e-15)
    # Upright limit is smooth: p(l) = (0, 0, l).
    np.testing.assert_allclose(kinematics_batch(np.zeros((1, 3)), l)[0], [[0, 0, l]], atol=1e-15)


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
    _, dtip, rot = kinematics_batch(q, l)
    R0 = head_rotation(q)[0]
    h = 1e-7
    for i in range(3):
        dq = np.zeros((1, 3))
        dq[0, i] = h
        tp, tm = kinematics_batch(q + dq, l)[0], kinematics_batch(q - dq, l)[0]
        np.testing.assert_allclose((tp - tm)[0] / (2 * h), dtip[0, i], atol=1e-7)
        W = (head_rotation(q + dq)[0] - head_rotation(q - dq)[0]) / (2 * h) @ R0.T
        axis = np.array([W[2, 1], W[0, 2], W[1, 0]])
        np.testing.assert_allclose(axis, rot[0, i], atol=1e-6)


def _geometry(c, q):
    tip, dtip, rot = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
    offset, unit, ext = np.empty((3, 3)), np.empty((3, 2, 3)), np.empty((3, 2))
    f1, f2 = kinematics(q[0], q[1], c[L.LENGTH], tip, dtip, rot)
    spring_geometry(c, q[0], q[1], q[2], f1, f2, tip, offset, unit, ext)
    return dtip, rot, offset, unit, ext


def _forces(c, q, tension):
    dtip, rot, offset, unit, _ = _geometry(c, q)
    qf, fmus = np.empty(3), np.empty((3, 3))
    generalized_forces(tension, unit, offset, dtip, rot, qf, fmus)
    return qf, fmus


def test_generalized_forces_equal_virtual_work(pc):
    # Q = -sum_f F_f dL_f/dq for fixed spring tensions (eq. 11 moment balance by virtual work).
    c = pc[0]
    q = np.array([0.25, 0.1, 0.02])
    tension = np.array([[3.0, 2.0], [1.0, 4.0], [0.5, 0.0]])
    Q, _ = _forces(c, q, tension)
    h = 1e-7
    for i in range(3):
        dq = np.zeros(3)
        dq[i] = h
        Lp = _geometry(c, q + dq)[4]  # extension = length - free length
        Lm = _geometry(c, q - dq)[4]
        assert Q[i] == pytest.approx(-np.sum(tension * (Lp - Lm) / (2 * h)), rel=1e-6, abs=1e-9)


def test_pennate_force_is_2Ff_cos_alpha(pc, params):
    # Upright pose, equal spring tensions: the tendon force is 2 F_f cos(alpha) (eq. 12).
    _, fmus = _forces(pc[0], np.zeros(3), np.full((3, 2), 5.0))
    alpha = math.radians(params.muscles.pennation_deg)
    np.testing.assert_allclose(np.linalg.norm(fmus, axis=-1), 2 * 5.0 * math.cos(alpha), rtol=1e-12)


# --- Whole plant ----------------------------------------------------------------------------

def test_zero_current_leaves_neck_upright(pc):
    tr, _ = simulate(pc, np.zeros((2000, 2, 3)))
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


def test_a_known_added_mass_does_not_tell_a_payload_from_a_softer_backbone(params):
    """The report's advice on `head_payload` (diagnose.SEPARATE) rests on this: upright, the
    head's weight is a negative stiffness, so a payload is a softer backbone, and a known mass
    added on top shifts both explanations alike. Weighing the head separates them (so would a
    head-down mount, which the model does not take: docs/gap-log.md, session 65)."""
    from scipy.optimize import minimize_scalar

    from neck_env.effects import G_M_S2
    amps = np.array([5.0, 6.0, 7.0, 8.0])
    cur = pulse_currents(amps, 0, 5.0, 12.0, 0.01)

    def theta(ei_scale, mass_kg, com_m):
        p = params.replace(backbone__bending_stiffness_Nm2=params.backbone.bending_stiffness_Nm2
                           * ei_scale)
        c = constants_from_params([p] * amps.size)
        c[:, L.PAYLOAD_MG] = mass_kg * G_M_S2  # as effects.apply_to_constants sets it
        c[:, L.PAYLOAD_COM] = com_m
        return simulate(c, cur, 0.01)[0].theta_deg

    def rms(a, b):
        return float(np.sqrt(np.mean((a - b) ** 2)))

    m0, h0, dm, hd = 0.20, 0.05, 0.10, 0.03  # unknown payload; known mass added, kg and m
    payload = theta(1.0, m0, h0)
    fit = minimize_scalar(lambda s: rms(theta(s, 0.0, h0), payload), bounds=(0.3, 1.2),
                          method="bounded", options={"xatol": 1e-3})
    assert fit.x < 0.95 and fit.fun < 0.1  # a softer backbone is the payload's bend
    m1, h1 = m0 + dm, (m0 * h0 + dm * hd) / (m0 + dm)
    with_mass, softer_with_mass = theta(1.0, m1, h1), theta(fit.x, dm, hd)
    assert rms(with_mass, payload) > 0.5  # the added mass shows ...
    assert rms(with_mass, softer_with_mass) < 0.1  # ... and both explanations follow it alike


def test_fatigue_is_permanent_set_not_lost_strain(pc):
    """A worn muscle (40 % of its recoverable strain turned into permanent set) rests exactly
    where a fresh one does -- cold, its springs pull as before -- and bends less when hot, by
    more the fuller the transformation (the set is paid back only in austenite). Strain that
    vanished instead would shorten the cold springs and tilt the neck toward them at rest."""
    worn_c = pc[:1].copy()
    worn_c[:, L.FATIGUE_MAX] = 0.4  # rate 0: the wear stays as set
    worn_x = initial_state(worn_c, 1)
    worn_x[:, L.S_FATIGUE] = 0.4
    cur = np.concatenate([np.zeros((200, 4, 3)), pulse_currents([5.0, 6.0, 7.0, 8.0], 0, 5.0, 10.0)])
    fresh, _ = simulate(np.repeat(pc[:1], 4, axis=0), cur)
    worn, _ = simulate(np.repeat(worn_c, 4, axis=0), cur, state=np.repeat(worn_x, 4, axis=0))
    assert np.abs(worn.theta_deg[:200]).max() < 1e-9  # upright at rest
    peak_fresh, peak_worn = fresh.theta_deg.max(axis=0), worn.theta_deg.max(axis=0)
    assert np.all(peak_worn < peak_fresh)
    assert peak_worn[3] < 0.8 * peak_fresh[3]  # 8 A: nearly full transformation


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
    tr, _ = simulate(constants_from_params([params, other]), cur)
    tr_a, _ = simulate(constants_from_params(params), cur[:, :1])
    tr_b, _ = simulate(constants_from_params(other), cur[:, 1:])
    np.testing.assert_allclose(tr.theta_deg[:, 0], tr_a.theta_deg[:, 0], atol=1e-12)
    np.testing.assert_allclose(tr.theta_deg[:, 1], tr_b.theta_deg[:, 0], atol=1e-12)
    assert abs(tr_a.theta_deg[-1, 0] - tr_b.theta_deg[-1, 0]) > 1.0


# --- Bad input ------------------------------------------------------------------------------

def test_non_finite_or_misshaped_currents_raise(pc):
    x = initial_state(pc, 2)
    with pytest.raises(ValueError, match="finite"):
        step(pc, x, np.array([[1.0, np.nan, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    with pytest.raises(ValueError, match="finite"):
        step(pc, x, np.array([[np.inf, 0.0, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        step(pc, x, np.zeros((2, 2)), 0.01)
    with pytest.raises(ValueError, match="dt_s > 0"):
        step(pc, x, np.zeros((2, 3)), -0.01)
