"""Column layout of the packed arrays the compiled plant works on.

The plant runs on three float64 arrays so one compiled call can advance thousands of rigs:

* constants ``(B, N_CONST)``: one row per rig (B = 1 shares a row among all rigs),
* state ``(N, N_STATE)``: one row per rig, updated by ``plant.step``,
* outputs ``(N, N_OUT)``: what a step reports.

Module-level integers are compile-time constants for numba. Units are in the comments.
"""

from __future__ import annotations


# --- constants: SMA spring (one representative spring; two per muscle) ---------------------
G_A = 0  # austenite shear modulus, Pa
G_M = 1  # martensite shear modulus, Pa
GAMMA_L = 2  # recoverable shear strain
SHEAR_PER_EXT = 3  # d / (pi n D^2), 1/m
FORCE_PER_SHEAR = 4  # pi d^3 / (8 D), m^2
THETA_SHEAR = 5  # thermoelastic coefficient in shear, Pa/K
AS = 6  # deg C, stress-free
AF = 7
MS = 8
MF = 9
C_A = 10  # stress influence, Pa/K (shear)
C_M = 11
HEAT_CAP = 12  # m c_p of one spring, J/K
LATENT_K = 13  # dH / c_p, K per unit xi
LATENT_J = 14  # m dH of one spring, J
R_M = 15  # resistance of one spring, martensite, ohm
R_A = 16
HA = 17  # convection h * wire surface, W/K
AMBIENT = 18  # deg C
# --- constants: backbone and muscles --------------------------------------------------------
LENGTH = 19  # m
K_BEND = 20  # EI / l, N m / rad
K_TWIST = 21  # GJ / l, N m / rad
DAMPING = 22  # N m s / rad
LEVER_SQ = 23  # (r_h cos alpha)^2 / 2, m^2 (implicit-stiffness estimate)
HEAD_R = 24  # tendon radius on the head, m
PSI = 25  # 25, 26, 27: muscle azimuths, rad
FREE_LEN = 28  # spring anchor-to-tendon length at zero extension, m
ANCHOR = 29  # 29 .. 46: base anchors [muscle k][spring s][xyz] at ANCHOR + 6k + 3s + i
# --- constants: effects (all neutral at their defaults, see neck_env.effects) -------------
PAYLOAD_MG = 47  # head weight m g, N (0 = gravity moment off)
PAYLOAD_COM = 48  # centre of mass above the head plate, m
VISCO_K = 49  # Maxwell-branch stiffness of the standard linear solid, N m / rad (0 = off)
VISCO_TAU = 50  # its relaxation time, s
FRICTION = 51  # Coulomb friction moment of the backbone, N m (0 = off)
SUPPLY_V = 52  # supply compliance voltage, V (inf = ideal current source)
WIRING_R = 53  # series resistance of leads and relay per muscle, ohm
COUPLING = 54  # heat conductance between each pair of muscles, W/K (0 = off)
CONV_GAIN = 55  # multiplier on h (1 = nominal)
CONV_TCOEF = 56  # relative change of h per K of excess temperature, 1/K (0 = constant h)
FATIGUE_RATE = 57  # loss of recoverable strain per unit of transformed fraction (0 = off)
FATIGUE_MAX = 58  # cap on that loss (fraction of gamma_L)
# --- constants: derived, for speed -----------------------------------------------------------
COS_PSI = 59  # 59..61: cos of the muscle azimuths
SIN_PSI = 62  # 62..64: sin of the muscle azimuths
INV_C_A = 65  # 1 / C_A, K/Pa (multiplications are cheaper than divisions in the hot loop)
INV_C_M = 66  # 1 / C_M
INV_BAND_A = 67  # 1 / (A_f - A_s), 1/K
INV_BAND_M = 68  # 1 / (M_s - M_f)
# --- constants: safety --------------------------------------------------------------------------
CUTOFF_C = 69  # spring temperature at which a muscle's current is cut (inf = no cut), deg C
# --- constants: heat drained into each muscle's terminals (crimps, anchor posts) -------------
TERM_G = 70  # conductance of one spring to its muscle's terminals, W/K (0 = no terminal path)
TERM_C = 71  # heat capacity of one muscle's terminals, J/K
TERM_LOSS = 72  # their loss to the air, W/K
# --- constants: how h depends on a spring's excess temperature ----------------------------------
CONV_EXP = 73  # h ~ (T - T_amb)^n about CONV_REF_DT_K above ambient (0 = constant h)
N_CONST = 74
CONV_REF_DT_K = 50.0  # where a still-air h equals the calibrated h (``Thermal.convection_exponent``)
CONV_MIN_DT_K = 1.0  # below this excess a still-air h is held (h -> 0 at ambient would never settle)

# --- state ----------------------------------------------------------------------------------
S_T = 0  # 0..2: spring temperature per muscle, deg C
S_XI = 3  # 3..5: martensite fraction
S_HEAT = 6  # 6..8: 1.0 on the heating branch, 0.0 on the cooling branch
S_SCALE = 9  # 9..11: branch scale through the last reversal point
S_Q = 12  # 12..14: b_x, b_y (rad), twist eps (rad)
S_VISCO = 15  # 15..17: Maxwell-branch moment on b_x, b_y, eps, N m
S_FATIGUE = 18  # 18..20: fractional loss of recoverable strain per muscle
S_TERM = 21  # 21..23: temperature of each muscle's terminals, deg C
N_STATE = 24

# --- outputs of one step --------------------------------------------------------------------
O_THETA = 0  # deg
O_PHI = 1  # deg in [0, 360)
O_POWER = 2  # 2..4: mean electrical power per muscle over the step (both springs), W
O_ENERGY = 5  # 5..7: electrical energy per muscle in the step, J
O_CURRENT = 8  # 8..10: mean current that flowed per muscle, A
O_FORCE = 11  # 11..13: tendon force magnitude at the end of the step, N
O_CONV = 14  # 14..16: mean heat loss per muscle over the step (both springs; air and terminals), W
N_OUT = 17
