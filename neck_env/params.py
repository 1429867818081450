"""Physical parameters of the SMA neck, as frozen dataclasses with units in their names.

Every value carries where it came from (``NeckParams.provenance``, keyed ``"group.field"``):

* ``paper``      -- stated in Das et al. (``shared/paper``),
* ``datasheet``  -- Dynalloy Flexinol technical data (typical NiTi values),
* ``assumed``    -- a design value the paper does not give (geometry of the rig),
* ``fitted``     -- set by ``python -m neck_env.calibration`` against the paper's Table 1.

The calibrated defaults live in ``neck_env/data/default_params.json`` and are what
``default_params()`` returns; the dataclass field defaults are the uncalibrated starting point.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

DEFAULT_PARAMS_PATH = Path(__file__).with_name("data") / "default_params.json"


def _require(cond: bool, group: str, name: str, value: Any, why: str) -> None:
    if not cond:
        raise ValueError(f"{group}.{name} = {value!r}: {why}")


def _positive(obj: Any, group: str, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        _require(
            isinstance(v, (int, float)) and math.isfinite(v) and v > 0,
            group, name, v, "must be a finite number > 0",
        )


def _finite(obj: Any, group: str, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        _require(isinstance(v, (int, float)) and math.isfinite(v), group, name, v, "must be finite")


@dataclass(frozen=True)
class SpringGeometry:
    """One SMA coil spring (each muscle holds two, electrically in series)."""

    wire_diameter_m: float = 0.8e-3
    coil_diameter_m: float = 5.0e-3  # mean coil diameter D
    active_coils: float = 14.0
    # Shear strain recovered by the martensite -> austenite transformation (gamma_L).
    recoverable_shear_strain: float = 0.03
    # Extension beyond the recoverable extension when installed straight: the cold pre-tension.
    pretension_extension_m: float = 2.0e-3

    def __post_init__(self) -> None:
        _positive(self, "spring", "wire_diameter_m", "coil_diameter_m", "active_coils",
                  "recoverable_shear_strain")
        _finite(self, "spring", "pretension_extension_m")
        _require(self.pretension_extension_m >= 0, "spring", "pretension_extension_m",
                 self.pretension_extension_m, "must be >= 0 (a slack install cannot actuate)")
        _require(self.coil_diameter_m > 2 * self.wire_diameter_m, "spring", "coil_diameter_m",
                 self.coil_diameter_m, "must exceed twice wire_diameter_m (spring index > 2)")
        _require(self.recoverable_shear_strain < 0.15, "spring", "recoverable_shear_strain",
                 self.recoverable_shear_strain, "must be < 0.15 (NiTi recovers < ~8 % tensile)")

    @property
    def wire_area_m2(self) -> float:
        return math.pi * self.wire_diameter_m**2 / 4

    @property
    def wire_length_m(self) -> float:
        return math.pi * self.coil_diameter_m * self.active_coils

    @property
    def surface_m2(self) -> float:
        """pi d L: the wire's cooling surface (h A is the convection coefficient times this)."""
        return math.pi * self.wire_diameter_m * self.wire_length_m

    @property
    def rate_factor_m(self) -> float:
        """d^4 / (8 n D^3): spring rate per unit shear modulus (eq. 1, A = G * this)."""
        return self.wire_diameter_m**4 / (8 * self.active_coils * self.coil_diameter_m**3)

    @property
    def force_per_shear_stress_m2(self) -> float:
        """pi d^3 / (8 D): axial force per unit wire shear stress (eq. 1, B and C)."""
        return math.pi * self.wire_diameter_m**3 / (8 * self.coil_diameter_m)

    @property
    def recoverable_extension_m(self) -> float:
        """Extension recovered on full transformation: gamma_L * pi n D^2 / d."""
        return (self.recoverable_shear_strain * math.pi * self.active_coils
                * self.coil_diameter_m**2 / self.wire_diameter_m)


@dataclass(frozen=True)
class SMAMaterial:
    """Flexinol-like NiTi. Transformation temperatures are the stress-free ones (deg C)."""

    youngs_austenite_Pa: float = 75e9
    youngs_martensite_Pa: float = 28e9
    poisson_ratio: float = 0.33
    As_C: float = 68.0
    Af_C: float = 78.0
    Ms_C: float = 52.0
    Mf_C: float = 42.0
    # Stress influence coefficients (Pa of wire shear stress per K): A_s' = A_s + tau / C_A.
    C_A_Pa_per_K: float = 8.0e6
    C_M_Pa_per_K: float = 8.0e6
    # Thermoelastic coefficient (tensile, Pa/K); enters the shear law divided by sqrt(3) (eq. 1, C).
    thermoelastic_Pa_per_K: float = 0.55e6
    density_kg_m3: float = 6450.0
    specific_heat_J_kgK: float = 837.0
    latent_heat_J_kg: float = 24.2e3
    resistivity_martensite_ohm_m: float = 76e-8
    resistivity_austenite_ohm_m: float = 82e-8

    def __post_init__(self) -> None:
        _positive(self, "material", "youngs_austenite_Pa", "youngs_martensite_Pa",
                  "C_A_Pa_per_K", "C_M_Pa_per_K", "density_kg_m3", "specific_heat_J_kgK",
                  "resistivity_martensite_ohm_m", "resistivity_austenite_ohm_m")
        _finite(self, "material", "As_C", "Af_C", "Ms_C", "Mf_C", "thermoelastic_Pa_per_K",
                "latent_heat_J_kg", "poisson_ratio")
        _require(0 <= self.poisson_ratio < 0.5, "material", "poisson_ratio",
                 self.poisson_ratio, "must lie in [0, 0.5)")
        _require(self.Af_C > self.As_C, "material", "Af_C", self.Af_C,
                 f"must exceed As_C = {self.As_C}")
        _require(self.Ms_C > self.Mf_C, "material", "Ms_C", self.Ms_C,
                 f"must exceed Mf_C = {self.Mf_C}")
        _require(self.latent_heat_J_kg >= 0, "material", "latent_heat_J_kg",
                 self.latent_heat_J_kg, "must be >= 0")
        _require(self.Af_C > self.Ms_C, "material", "Af_C", self.Af_C,
                 f"must exceed Ms_C = {self.Ms_C} (a hysteresis loop needs Af > Ms)")


@dataclass(frozen=True)
class Thermal:
    """Heat exchange of a spring with the air."""

    convection_W_m2K: float = 60.0  # effective h_T over the wire surface
    ambient_C: float = 25.0
    # Heat a spring drains into its muscle's terminals (crimps, anchor posts): a second, slower
    # thermal mass per muscle that sheds to the air. 0 W/K is none, as calibrated: Table 1 is
    # heating-only data and cannot see it; a rig's cooling tails can (neck_env.gap fits it).
    terminal_conductance_W_K: float = 0.0  # one spring <-> its muscle's terminals
    terminal_heat_capacity_J_K: float = 1.5  # one muscle's terminals
    terminal_loss_W_K: float = 0.03  # one muscle's terminals -> air
    # h ~ (T - T_amb)^n, equal to convection_W_m2K 50 K above ambient (``layout.CONV_REF_DT_K``):
    # 0 is a constant h, as calibrated (a forced draft); free convection about a thin wire in
    # still air goes as 0.15-0.25 (Morgan's Nu ~ Ra^n from Ra ~ 1 to 1e7)
    convection_exponent: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "thermal", "convection_W_m2K", "terminal_heat_capacity_J_K")
        _finite(self, "thermal", "ambient_C", "terminal_conductance_W_K", "terminal_loss_W_K",
                "convection_exponent")
        _require(0 <= self.convection_exponent <= 1, "thermal", "convection_exponent",
                 self.convection_exponent, "must lie in [0, 1]")
        _require(-40 <= self.ambient_C <= 60, "thermal", "ambient_C", self.ambient_C,
                 "must lie in [-40, 60] deg C")
        for name in ("terminal_conductance_W_K", "terminal_loss_W_K"):
            _require(getattr(self, name) >= 0, "thermal", name, getattr(self, name), "must be >= 0")


@dataclass(frozen=True)
class Backbone:
    """The TPU continuum backbone (constant curvature, Euler-Bernoulli bending and torsion)."""

    length_m: float = 0.10
    bending_stiffness_Nm2: float = 0.10  # EI
    torsional_stiffness_Nm2: float = 0.10  # GJ
    # Viscous damping of the bending/twist angles (N m s / rad). Head inertia is neglected: the
    # mechanical time scale (~0.1 s) is far below the thermal one (seconds), see physics.backbone.
    damping_Nms_per_rad: float = 0.05

    def __post_init__(self) -> None:
        _positive(self, "backbone", "length_m", "bending_stiffness_Nm2",
                  "torsional_stiffness_Nm2", "damping_Nms_per_rad")


@dataclass(frozen=True)
class MuscleGeometry:
    """Three bipennate muscles around the backbone."""

    azimuths_deg: tuple[float, float, float] = (180.0, 60.0, 300.0)
    head_radius_m: float = 0.035  # tendon attachment radius on the head mount
    base_radius_m: float = 0.035  # radius of the spring anchors on the base plate
    pennation_deg: float = 20.0  # alpha in the straight pose

    def __post_init__(self) -> None:
        az = self.azimuths_deg
        _require(isinstance(az, (tuple, list)) and len(az) == 3
                 and all(isinstance(a, (int, float)) and math.isfinite(a) for a in az),
                 "muscles", "azimuths_deg", az, "must be three finite angles in degrees")
        object.__setattr__(self, "azimuths_deg", tuple(float(a) for a in az))
        _positive(self, "muscles", "head_radius_m", "base_radius_m", "pennation_deg")
        _require(self.pennation_deg < 60, "muscles", "pennation_deg", self.pennation_deg,
                 "must be < 60 deg")


@dataclass(frozen=True)
class Head:
    """Head mount + display on top of the backbone."""

    mass_kg: float = 0.250
    com_height_m: float = 0.03  # centre of mass above the head plate

    def __post_init__(self) -> None:
        _positive(self, "head", "mass_kg")
        _finite(self, "head", "com_height_m")


_GROUPS = {
    "spring": SpringGeometry,
    "material": SMAMaterial,
    "thermal": Thermal,
    "backbone": Backbone,
    "muscles": MuscleGeometry,
    "head": Head,
}

_BASE_PROVENANCE = {
    "spring.wire_diameter_m": "assumed: thick enough to take 4-8 A for seconds (paper gives none)",
    "spring.coil_diameter_m": "assumed",
    "spring.active_coils": "assumed",
    "spring.recoverable_shear_strain": "datasheet: ~4-5 % tensile recovery, as shear / sqrt(3)",
    "spring.pretension_extension_m": "assumed: taut install, small cold pre-tension",
    "material.youngs_austenite_Pa": "datasheet: Flexinol 75-83 GPa",
    "material.youngs_martensite_Pa": "datasheet: Flexinol 28-41 GPa",
    "material.poisson_ratio": "datasheet",
    "material.As_C": "datasheet: Flexinol 70 C alloy",
    "material.Af_C": "datasheet: Flexinol 70 C alloy",
    "material.Ms_C": "datasheet: Flexinol 70 C alloy",
    "material.Mf_C": "datasheet: Flexinol 70 C alloy",
    "material.C_A_Pa_per_K": "datasheet: ~6-14 MPa/K (Brinson), shear",
    "material.C_M_Pa_per_K": "datasheet: ~6-14 MPa/K (Brinson), shear",
    "material.thermoelastic_Pa_per_K": "datasheet: 0.55 MPa/K (Brinson)",
    "material.density_kg_m3": "datasheet: 6.45 g/cm3",
    "material.specific_heat_J_kgK": "datasheet: 0.2 cal/(g K)",
    "material.latent_heat_J_kg": "datasheet: 5.78 cal/g",
    "material.resistivity_martensite_ohm_m": "datasheet: 76 uOhm cm",
    "material.resistivity_austenite_ohm_m": "datasheet: 82 uOhm cm",
    "thermal.convection_W_m2K": "assumed: still air around a fine wire",
    "thermal.ambient_C": "paper: experiments at room temperature",
    "thermal.terminal_conductance_W_K": "assumed: no heat path to the terminals (Table 1 cannot see one)",
    "thermal.terminal_heat_capacity_J_K": "assumed: brass crimps and a printed post, ~1.5 J/K",
    "thermal.terminal_loss_W_K": "assumed: a few cm^2 of terminal in still air",
    "thermal.convection_exponent": "assumed: a constant h (Table 1 is heating-only data)",
    "backbone.length_m": "assumed",
    "backbone.bending_stiffness_Nm2": "assumed: serrated TPU",
    "backbone.torsional_stiffness_Nm2": "assumed: serrated TPU",
    "backbone.damping_Nms_per_rad": "assumed: TPU damping, no overshoot seen in the paper",
    "muscles.azimuths_deg": "paper: 180, 60, 300 deg",
    "muscles.head_radius_m": "assumed",
    "muscles.base_radius_m": "assumed",
    "muscles.pennation_deg": "assumed",
    "head.mass_kg": "paper: head mount + display 250 g",
    "head.com_height_m": "assumed",
}


@dataclass(frozen=True)
class NeckParams:
    """All parameters of one rig. Immutable; use ``replace`` to derive variants."""

    spring: SpringGeometry = field(default_factory=SpringGeometry)
    material: SMAMaterial = field(default_factory=SMAMaterial)
    thermal: Thermal = field(default_factory=Thermal)
    backbone: Backbone = field(default_factory=Backbone)
    muscles: MuscleGeometry = field(default_factory=MuscleGeometry)
    head: Head = field(default_factory=Head)
    # "group.field" -> where the value came from. Not part of equality.
    provenance: Mapping[str, str] = field(default_factory=lambda: dict(_BASE_PROVENANCE),
                                          compare=False, hash=False)

    def __post_init__(self) -> None:
        for name, cls in _GROUPS.items():
            value = getattr(self, name)
            if not isinstance(value, cls):
                raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")

    # -- derivation -------------------------------------------------------------------------
    def replace(self, source: str | None = None, **changes: float) -> "NeckParams":
        """Return a copy with ``changes`` given as ``"group.field"=value`` style kwargs.

        Keys use a double underscore instead of the dot: ``replace(thermal__convection_W_m2K=80)``.
        ``source`` (if given) is recorded as the provenance of every changed field.
        """
        groups: dict[str, dict[str, Any]] = {}
        for key, value in changes.items():
            group, _, name = key.partition("__")
            if group not in _GROUPS or name not in {f.name for f in fields(_GROUPS[group])}:
                raise ValueError(f"unknown parameter {group}.{name}")
            groups.setdefault(group, {})[name] = value
        kwargs = {g: dataclasses.replace(getattr(self, g), **ch) for g, ch in groups.items()}
        prov = dict(self.provenance)
        if source is not None:
            for key in changes:
                prov[key.replace("__", ".")] = source
        return dataclasses.replace(self, provenance=prov, **kwargs)

    def get(self, dotted: str) -> float:
        group, _, name = dotted.partition(".")
        if group not in _GROUPS or not hasattr(getattr(self, group), name):
            raise ValueError(f"unknown parameter {dotted}")
        return getattr(getattr(self, group), name)

    # -- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {g: dataclasses.asdict(getattr(self, g)) for g in _GROUPS}
        out["muscles"]["azimuths_deg"] = list(self.muscles.azimuths_deg)
        out["provenance"] = dict(sorted(self.provenance.items()))
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], origin: str = "<dict>") -> "NeckParams":
        if not isinstance(data, Mapping):
            raise ValueError(f"{origin}: expected a JSON object of parameter groups")
        unknown = set(data) - set(_GROUPS) - {"provenance"}
        if unknown:
            raise ValueError(f"{origin}: unknown parameter group(s) {sorted(unknown)}; "
                             f"expected {sorted(_GROUPS)} and 'provenance'")
        kwargs: dict[str, Any] = {}
        for gname, gcls in _GROUPS.items():
            gdata = data.get(gname, {})
            if not isinstance(gdata, Mapping):
                raise ValueError(f"{origin}: group {gname!r} must be a JSON object")
            known = {f.name for f in fields(gcls)}
            bad = set(gdata) - known
            if bad:
                raise ValueError(f"{origin}: unknown field(s) {sorted(f'{gname}.{b}' for b in bad)}")
            values = dict(gdata)
            if "azimuths_deg" in values:
                values["azimuths_deg"] = tuple(values["azimuths_deg"])
            kwargs[gname] = gcls(**values)
        prov = dict(_BASE_PROVENANCE)
        prov.update(data.get("provenance", {}))
        return cls(provenance=prov, **kwargs)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "NeckParams":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from exc
        return cls.from_dict(data, origin=str(path))


def default_params() -> NeckParams:
    """The calibrated defaults (fitted to the paper's Table 1, see ``neck_env.calibration``)."""
    if DEFAULT_PARAMS_PATH.exists():
        return NeckParams.load(DEFAULT_PARAMS_PATH)
    return NeckParams()


def resolve_params(params: "NeckParams | str | Path | None") -> "NeckParams":
    """A ``NeckParams`` from itself, a JSON path, or ``None`` (the calibrated defaults)."""
    if params is None:
        return default_params()
    if isinstance(params, NeckParams):
        return params
    if isinstance(params, (str, Path)):
        return NeckParams.load(params)
    raise ValueError(f"params must be a NeckParams, a JSON path or None, got {type(params).__name__}")
