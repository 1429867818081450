"""The catalogue of unmodelled effects: switchable, parameterised changes to the plant or sensor.

Each effect has physical parameter ranges and a note on the signature it leaves in recordings;
the sim-to-real diagnosis (``neck_env.gap``) refits them, the environment can switch them on
(``NeckTrack-v0(effects=...)``) so policies can be trained robust to them.

How each one acts:

* plant effects set columns of the packed constants (``physics.layout``) that the compiled plant
  reads (``apply_to_constants``),
* ``imu_misalignment`` rotates the IMU in the head frame (``imu_mount``),
* ``actuation_delay`` delays the commanded currents (``delay_s``),
* ``gyro_bias_drift`` is *not* in the catalogue the diagnosis searches: it exists for the blind
  evaluation (an effect the tool must call unexplained).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .physics import layout as L

G_M_S2 = 9.81


@dataclass(frozen=True)
class EffectParam:
    low: float  # the range magnitudes are drawn from (a typical rig with the effect)
    high: float
    unit: str
    doc: str
    valid_high: float | None = None  # accepted up to here (e.g. up to "off"); default: high

    @property
    def upper(self) -> float:
        return self.high if self.valid_high is None else self.valid_high


@dataclass(frozen=True)
class Effect:
    name: str
    kind: str  # "plant", "sensor" or "actuation"
    params: Mapping[str, EffectParam]
    signature: str  # what it leaves in the data
    in_catalogue: bool = True
    doc: str = ""
    defaults: Mapping[str, float] = field(default_factory=dict)  # a typical magnitude
    # Parameters that ``sample`` holds at their default (e.g. a draft's onset: 0 in an episode).
    held: tuple[str, ...] = ()
    # It changes the springs' temperatures for given commands: thermistors see it even on a
    # neck that never moves (the diagnosis names only these when nothing actuated).
    thermal: bool = False
    # It grows with use and is carried from recording to recording: a recording early in the
    # session holds little or none of it (the diagnosis judges it where it has built up).
    builds_up: bool = False

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        """Parameters drawn uniformly within their ranges (``held`` ones at their default)."""
        return {k: (float(self.defaults[k]) if k in self.held else float(rng.uniform(p.low, p.high)))
                for k, p in self.params.items()}

    def check(self, values: Mapping[str, float]) -> dict[str, float]:
        """Validate a parameter dict: known names, finite, within range (raise ValueError)."""
        unknown = set(values) - set(self.params)
        if unknown:
            raise ValueError(f"effect {self.name}: unknown parameter(s) {sorted(unknown)}; "
                             f"expected {sorted(self.params)}")
        out = dict(self.defaults)
        for k, v in values.items():
            p = self.params[k]
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"effect {self.name}: {k} = {v!r} must be a finite number")
            if not (p.low - 1e-12 <= v <= p.upper + 1e-12):
                raise ValueError(f"effect {self.name}: {k} = {v} outside its range "
                                 f"[{p.low}, {p.upper}] {p.unit}")
            out[k] = float(v)
        missing = set(self.params) - set(out)
        if missing:
            raise ValueError(f"effect {self.name}: missing parameter(s) {sorted(missing)}")
        return out


def _effect(name, kind, signature, params, defaults, doc="", in_catalogue=True,
            held=(), thermal=False, builds_up=False) -> Effect:
    return Effect(name, kind, {k: EffectParam(*v) for k, v in params.items()}, signature,
                  in_catalogue, doc, defaults, tuple(held), thermal, builds_up)


EFFECTS: dict[str, Effect] = {e.name: e for e in [
    _effect(
        "imu_misalignment", "sensor",
        "a constant phi offset at every tilt (yaw); a tilt reading when upright that shifts "
        "theta and phi most at small tilts (mount tilt); temperatures and timing unaffected",
        {"yaw_deg": (-25.0, 25.0, "deg", "rotation of the IMU about the head axis"),
         "tilt_deg": (0.0, 6.0, "deg", "tilt of the IMU board on the head mount"),
         "tilt_dir_deg": (0.0, 360.0, "deg", "direction of that tilt in the head frame")},
        {"yaw_deg": 10.0, "tilt_deg": 2.0, "tilt_dir_deg": 0.0},
        "The paper blames its phi offset on exactly this."),
    _effect(
        "head_payload", "plant",
        "more bending than nominal for the same heating, growing with theta (gravity moment "
        "~ m g h sin theta helps the bend once bent), slower return while cooling",
        {"mass_kg": (0.1, 0.4, "kg", "head mount + display"),
         "com_height_m": (0.0, 0.08, "m", "centre of mass above the head plate")},
        {"mass_kg": 0.25, "com_height_m": 0.03},
        "Gravity moment of the head on the vertical backbone."),
    _effect(
        "backbone_viscoelasticity", "plant",
        "creep: theta keeps drifting for seconds after the muscle force settles; a fast partial "
        "then slow full return when released; rate-dependent stiffness",
        {"stiffness_ratio": (0.3, 3.0, "-", "Maxwell-branch stiffness / backbone EI/l"),
         "tau_s": (0.5, 8.0, "s", "relaxation time")},
        {"stiffness_ratio": 1.0, "tau_s": 3.0},
        "TPU as a standard linear solid."),
    _effect(
        "supply_limit", "plant",
        "high commanded currents act like lower ones (the supply runs out of compliance "
        "voltage as the springs' resistance loads it); low currents unaffected; heating rate "
        "saturates with command",
        {"compliance_V": (2.5, 6.0, "V", "supply voltage limit (accepted up to 40 V: above "
                          "~8 V no current is limited, the effect is off)", 40.0),
         "wiring_ohm": (0.05, 0.3, "ohm", "leads and relay contact per muscle")},
        {"compliance_V": 4.0, "wiring_ohm": 0.1},
        "Commanded currents are what the host knows; what flows is min(I, V / R_load).",
        held=(), thermal=True),
    _effect(
        "actuation_delay", "actuation",
        "every response (theta, temperature) starts late by the same time after a command "
        "edge, at every current and muscle; shapes otherwise unchanged",
        {"delay_s": (0.1, 1.0, "s", "relay + link latency")},
        {"delay_s": 0.3},
        "Commands take effect late.", thermal=True),
    _effect(
        "thermal_coupling", "plant",
        "unpowered muscles warm while a neighbour is heated; the heated spring runs slightly "
        "cooler; antagonist pre-warming reduces theta",
        {"conductance_W_K": (0.003, 0.03, "W/K", "heat conductance between each pair of muscles")},
        {"conductance_W_K": 0.01},
        "Heat exchanged between muscles through the head mount and air.", thermal=True),
    _effect(
        "convection_change", "plant",
        "what no constant convection coefficient produces: cooling fast when hot and slow near "
        "ambient, less heating at high currents than at low ones (h grows with temperature), or "
        "every time constant changing from one recording on (a draft starts). A constant gain "
        "from the start is the same as a different h: the diagnosis calls it a recalibration "
        "(ambiguous with h), not an effect. Springs in still air grow their h by themselves "
        "(free convection, h ~ dT^0.15-0.33): the diagnosis fits that law beside it; a named "
        "growth it matches says so, and with --still-air only a growth that beats it (or a "
        "draft) is named",
        {"gain": (0.4, 2.5, "-", "h multiplier while the draft blows"),
         "tcoef_per_K": (0.0, 0.012, "1/K", "relative change of h per K above ambient"),
         "onset_s": (0.0, 3600.0, "s", "recorded time (dataset clock, recordings back to back) "
                     "at which the draft starts; environments apply it from the episode start")},
        {"gain": 1.5, "tcoef_per_K": 0.0, "onset_s": 0.0},
        "A draft that starts during the experiments, or a temperature-dependent h.",
        held=("onset_s",), thermal=True),
    _effect(
        "sma_fatigue", "plant",
        "bending amplitude falls from recording to recording as the springs cycle, most at "
        "the currents that transform the springs fully; the rest reading does not move (the "
        "recoverable strain lost stays in the wire as permanent set: the cold spring pulls as "
        "before, the hot one less)",
        {"rate": (0.005, 0.05, "-", "loss of recoverable strain per unit transformed fraction"),
         "max_loss": (0.1, 0.5, "-", "cap on the loss, fraction of gamma_L")},
        {"rate": 0.02, "max_loss": 0.3},
        "Recoverable strain decays with cycles.", builds_up=True),
    _effect(
        "backbone_friction", "plant",
        "a dead band: no motion until the muscle moment exceeds a threshold; the head sticks "
        "at a residual tilt after cooling; stair-steps in slow moves",
        {"friction_Nm": (0.005, 0.05, "N m", "Coulomb friction moment")},
        {"friction_Nm": 0.02},
        "Coulomb friction / stiction in the serrated backbone."),
    _effect(
        "gyro_bias_drift", "sensor",
        "slow drift of the fused tilt (theta, phi) away from the truth that grows with time "
        "and is the same whether or not a muscle is heated",
        {"drift_dps_per_s": (0.002, 0.02, "deg/s per s", "growth rate of the gyro bias")},
        {"drift_dps_per_s": 0.01},
        "Held out of the catalogue: the diagnosis must call it unexplained.",
        in_catalogue=False, builds_up=True),
]}

CATALOGUE = tuple(n for n, e in EFFECTS.items() if e.in_catalogue)


def check_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict[str, float]]:
    """Validate a mapping effect name -> parameters (missing parameters take their defaults)."""
    if effects is None:
        return {}
    if not isinstance(effects, Mapping):
        raise ValueError(f"effects must be a mapping name -> parameters, got {type(effects).__name__}")
    out = {}
    for name, values in effects.items():
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {sorted(EFFECTS)}")
        out[name] = EFFECTS[name].check(values or {})
    return out


def apply_to_constants(consts: np.ndarray, effects: Mapping[str, Mapping[str, float]]) -> np.ndarray:
    """Copy of ``consts`` (B, N_CONST) with the plant effects switched on."""
    c = np.array(consts, dtype=float)
    for name, p in effects.items():
        if name == "head_payload":
            c[:, L.PAYLOAD_MG] = p["mass_kg"] * G_M_S2
            c[:, L.PAYLOAD_COM] = p["com_height_m"]
        elif name == "backbone_viscoelasticity":
            c[:, L.VISCO_K] = p["stiffness_ratio"] * c[:, L.K_BEND]
            c[:, L.VISCO_TAU] = p["tau_s"]
        elif name == "supply_limit":
            c[:, L.SUPPLY_V] = p["compliance_V"]
            c[:, L.WIRING_R] = p["wiring_ohm"]
        elif name == "thermal_coupling":
            c[:, L.COUPLING] = p["conductance_W_K"]
        elif name == "convection_change":
            c[:, L.CONV_GAIN] = p["gain"]
            c[:, L.CONV_TCOEF] = p["tcoef_per_K"]
        elif name == "sma_fatigue":
            c[:, L.FATIGUE_RATE] = p["rate"]
            c[:, L.FATIGUE_MAX] = p["max_loss"]
        elif name == "backbone_friction":
            c[:, L.FRICTION] = p["friction_Nm"]
    return c


def imu_mount(effects: Mapping[str, Mapping[str, float]]) -> np.ndarray:
    """Rotation (3, 3) of the IMU in the head frame (identity unless imu_misalignment)."""
    p = effects.get("imu_misalignment")
    if p is None:
        return np.eye(3)
    yaw = math.radians(p["yaw_deg"])
    tilt = math.radians(p["tilt_deg"])
    d = math.radians(p["tilt_dir_deg"])
    rz = lambda a: np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    ry = np.array([[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0], [-math.sin(tilt), 0, math.cos(tilt)]])
    return rz(d) @ ry @ rz(-d) @ rz(yaw)


def delay_s(effects: Mapping[str, Mapping[str, float]]) -> float:
    p = effects.get("actuation_delay")
    return 0.0 if p is None else p["delay_s"]


def gyro_drift(effects: Mapping[str, Mapping[str, float]]) -> float:
    """Gyro bias growth rate (deg/s per s); 0 unless gyro_bias_drift."""
    p = effects.get("gyro_bias_drift")
    return 0.0 if p is None else p["drift_dps_per_s"]
