"""The NeckTrack task, defined once: what the simulated envs, the rig env, the SB3 adapter and
the controllers agree on.

``Task`` (frozen) holds the task's settings -- action mode, control period, episode length,
energy budget, supply current, over-temperature cut, target distribution -- and applies the
task's rules:

| rule | where |
|---|---|
| action and observation spaces | ``Task.action_space``, ``Task.observation_space`` |
| action validation and scaling | ``Task.currents_A``: NaN/inf, a wrong shape, a non-numeric dtype or (relay mode) values other than 0/1 raise ``ValueError``; currents are clipped to [0, 8] A (as Gymnasium's Box-action envs clip); a relay that is on passes ``supply_current_A`` |
| over-temperature cut | ``Task.cut_hot``: the plant's ``over_temperature`` rule on observed temperatures |
| energy budget | ``Task.budget_energy_scale``: the plant's ``budget_energy_scale`` rule; ``budget_fraction_left`` for the observation |
| info dict | ``step_info``: the keys of every env's ``info`` (``INFO_KEYS``) |
| targets | ``Task.sample_targets``: one seeded trajectory (same seed, same targets in sim and on the rig) |
| keyword arguments | ``Task.from_kwargs`` / ``Task.split_kwargs`` / ``Task.to_kwargs``: the env keyword arguments a policy file stores, round-tripped through JSON |

The plant applies the over-temperature and budget rules inside its compiled step (the same
functions, ``neck_env.physics.plant``); the rig env applies them through this object before it
commands the relays.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np
from gymnasium import spaces

from .actuation import ACTUATIONS, max_equivalent_current_A
from .observation import observation_space
from .physics.compile import jit
from .physics.plant import budget_energy_scale, over_temperature
from .targets import TargetSpec, sample_targets

__all__ = ["Task", "ACTION_MODES", "MAX_CURRENT_A", "CONTROL_DT_S", "DEFAULT_EPISODE_S",
           "DEFAULT_SUPPLY_A", "DEFAULT_BUDGET_J", "DEFAULT_CUTOFF_C", "INFO_KEYS", "step_info",
           "budget_fraction_left"]

ACTION_MODES = ("current", "relay")
MAX_CURRENT_A = 8.0  # the rig's supply range is 4-8 A
CONTROL_DT_S = 0.05  # control period: one env step (the plant's experiments use 0.01 s)
DEFAULT_EPISODE_S = 60.0
DEFAULT_SUPPLY_A = 7.0  # calibrated Table 1: a 5 s pulse at 7 A reaches ~24 deg (task range)
DEFAULT_BUDGET_J = 1500.0  # see README "Energy budget"
# Over-temperature cut, as the rig firmware does with thermistors fitted: overheated Flexinol
# loses its trained shape. 160 C is above the ~90-150 C a controller needs for the target range.
DEFAULT_CUTOFF_C = 160.0

#: Keys of every NeckTrack env's ``info`` (the rig env adds its own after these).
INFO_KEYS = ("theta_deg", "phi_deg", "temperatures_C", "energy_J", "currents_A",
             "tracking_error_deg", "target_theta_deg", "target_phi_deg", "energy_left_J",
             "budget_exhausted")

# Action check results of the compiled pass.
_OK, _NOT_FINITE, _NOT_BINARY = 0, 1, 2


@dataclass(frozen=True)
class Task:
    """Everything that defines a NeckTrack task instance (shared by the sim and rig envs).

    Field names are the env keyword arguments (``gymnasium.make("NeckTrack-v0", dt=...)``).
    """

    action_mode: str = "current"
    dt: float = CONTROL_DT_S  # control period, s; one plant step per control step
    episode_s: float = DEFAULT_EPISODE_S
    energy_budget_J: float = DEFAULT_BUDGET_J  # float("inf") for none
    supply_current_A: float = DEFAULT_SUPPLY_A  # what an "on" relay passes
    cutoff_C: float = DEFAULT_CUTOFF_C  # a muscle's current is cut while its spring is hotter
    targets: TargetSpec = field(default_factory=TargetSpec)
    # what reaches the springs: "ideal" (the command, steadily) or "firmware" (what the rig's
    # firmware makes of it: duty windows, 80 % cap, on-time cap; neck_env.actuation)
    actuation: str = "ideal"

    def __post_init__(self) -> None:
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        if self.actuation not in ACTUATIONS:
            raise ValueError(f"actuation must be one of {ACTUATIONS}, got {self.actuation!r}")
        if not (_is_number(self.dt) and 0.001 <= self.dt <= 1.0):
            raise ValueError(f"dt = {self.dt!r}: must be a number of seconds in [0.001, 1]")
        if not (_is_number(self.episode_s) and self.dt <= self.episode_s < 1e6):
            raise ValueError(f"episode_s = {self.episode_s!r}: must be >= dt and finite")
        b = self.energy_budget_J
        if not (_is_number(b) and b > 0 and not math.isnan(b)):
            raise ValueError(f"energy_budget_J = {b!r}: must be > 0 (float('inf') for none)")
        if not (_is_number(self.cutoff_C) and self.cutoff_C > 40):
            raise ValueError(f"cutoff_C = {self.cutoff_C!r}: must be > 40 C (float('inf') for none)")
        if not (_is_number(self.supply_current_A) and 0 < self.supply_current_A <= MAX_CURRENT_A):
            raise ValueError(f"supply_current_A = {self.supply_current_A!r}: must lie in "
                             f"(0, {MAX_CURRENT_A}] A")
        if not isinstance(self.targets, TargetSpec):
            raise ValueError(f"targets must be a TargetSpec (or its fields as a dict), got "
                             f"{type(self.targets).__name__}")

    # -- keyword arguments (what a policy file stores) -----------------------------------------
    @staticmethod
    def field_names() -> tuple[str, ...]:
        """The task's keyword arguments (a subclass's extra fields are not task arguments)."""
        return tuple(f.name for f in fields(Task))

    @classmethod
    def split_kwargs(cls, kwargs: Mapping[str, Any] | None) -> tuple["Task", dict[str, Any]]:
        """(the task from the task's keys of ``kwargs``, the other keys untouched). ``targets``
        may be a ``TargetSpec`` or its fields as a mapping (as JSON stores it); ``None`` values
        mean the default."""
        kw = dict(kwargs or {})
        mine = {k: kw.pop(k) for k in Task.field_names() if k in kw and kw[k] is not None}
        if "targets" in mine and isinstance(mine["targets"], Mapping):
            mine["targets"] = _target_spec(mine["targets"])
        return Task(**mine), kw

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any] | None, *, ignore_unknown: bool = False) -> "Task":
        """The task from env keyword arguments; unknown keys raise ``TypeError`` unless
        ``ignore_unknown`` (e.g. a policy's ``env_kwargs`` also name ``params`` or ``effects``)."""
        task, rest = cls.split_kwargs(kwargs)
        if rest and not ignore_unknown:
            raise TypeError(f"unknown task argument(s) {sorted(rest)}; known: "
                            f"{list(cls.field_names())}")
        return task

    def to_kwargs(self) -> dict[str, Any]:
        """JSON-ready keyword arguments; ``Task.from_kwargs(t.to_kwargs()) == t``."""
        out = {name: getattr(self, name) for name in Task.field_names()}
        out["targets"] = dataclasses.asdict(self.targets)
        return out

    # -- spaces ----------------------------------------------------------------------------
    @property
    def action_space(self) -> spaces.Space:
        if self.action_mode == "relay":
            return spaces.MultiBinary(3)
        return spaces.Box(0.0, MAX_CURRENT_A, (3,), dtype=np.float32)

    @property
    def observation_space(self) -> spaces.Box:
        return observation_space()

    @property
    def episode_steps(self) -> int:
        return int(round(self.episode_s / self.dt))

    @property
    def max_current_A(self) -> float:
        """Largest (steady-equivalent) current an action can make flow: the supply in relay
        mode; 8 A in current mode, or through the firmware the duty cap's ``sqrt(0.8) I_s``."""
        if self.action_mode == "relay":
            return self.supply_current_A
        if self.actuation == "firmware":
            return min(MAX_CURRENT_A, max_equivalent_current_A(self.supply_current_A))
        return MAX_CURRENT_A

    # -- actions ---------------------------------------------------------------------------
    def currents_A(self, action, num_envs: int | None = None) -> np.ndarray:
        """Commanded currents (N, 3) float64, A, for one action (``num_envs`` None: shape (3,))
        or a batch ((num_envs, 3)); raises ``ValueError`` naming what is wrong."""
        a = np.asarray(action)
        want = (3,) if num_envs is None else (num_envs, 3)
        if a.shape != want:
            raise ValueError(f"action must have shape {want}, got {a.shape}")
        if a.dtype.kind not in "biuf":
            raise ValueError(f"action must be numeric, got dtype {a.dtype}")
        a = a.reshape(-1, 3)
        out = np.empty(a.shape)
        # compiled per input dtype: no float64 copy of the action on the way
        code = _action_to_currents(a, self.action_mode == "relay", self.supply_current_A,
                                   MAX_CURRENT_A, out)
        if code == _NOT_FINITE:
            a = a.astype(np.float64)
            raise ValueError(f"action must be finite, got {a[~np.isfinite(a)][:3]}")
        if code == _NOT_BINARY:
            a = a.astype(np.float64)
            raise ValueError(f"relay action must be 0 or 1 per muscle, got "
                             f"{a[~np.isin(a, (0.0, 1.0))][:3]}")
        return out

    # -- rules the rig applies (the plant applies the same functions in its step) -----------
    def cut_hot(self, currents_A: np.ndarray, temperatures_C: np.ndarray) -> np.ndarray:
        """Currents with every muscle at or above ``cutoff_C`` set to 0 (a new array)."""
        out = np.array(currents_A, dtype=float)
        for k in range(out.shape[-1]):
            if over_temperature(float(temperatures_C[k]), self.cutoff_C):
                out[..., k] = 0.0
        return out

    @staticmethod
    def budget_energy_scale(planned_J: float, left_J: float) -> float:
        """Factor on a step's planned energy that keeps it within the budget left."""
        return float(budget_energy_scale(float(planned_J), float(left_J)))

    def budget_fraction_left(self, energy_left_J: float) -> float:
        return float(budget_fraction_left(energy_left_J, self.energy_budget_J))

    # -- targets ---------------------------------------------------------------------------
    def max_target_segments(self) -> int:
        return self.targets.max_segments(self.episode_s)

    def sample_targets(self, rng: np.random.Generator, max_segments: int | None = None):
        """One target trajectory (t0, ramp, waypoints, segments used) from ``rng``."""
        m = self.max_target_segments() if max_segments is None else max_segments
        return sample_targets(self.targets, self.episode_s, rng, m)


@jit
def budget_fraction_left(energy_left_J, budget_J):
    """Observation entry 7: the budget's fraction left (1 without a budget)."""
    return energy_left_J / budget_J if budget_J < np.inf else 1.0


@jit
def _action_to_currents(a, relay, supply_A, max_current_A, out):
    """One pass over an (N, 3) action: check it, write currents into ``out``."""
    for i in range(a.shape[0]):
        for k in range(3):
            v = float(a[i, k])
            if not math.isfinite(v):
                return _NOT_FINITE
            if relay:
                if v != 0.0 and v != 1.0:
                    return _NOT_BINARY
                out[i, k] = v * supply_A
            else:
                out[i, k] = min(max(v, 0.0), max_current_A)
    return _OK


def step_info(*, theta_deg, phi_deg, temperatures_C, energy_J, currents_A, tracking_error_deg,
              target_theta_deg, target_phi_deg, energy_left_J, budget_exhausted=None) -> dict[str, Any]:
    """The ``info`` of a NeckTrack step (scalars for one env, arrays for a batch).
    ``budget_exhausted`` defaults to ``energy_left_J <= 0``."""
    if budget_exhausted is None:
        budget_exhausted = energy_left_J <= 0.0
    return {"theta_deg": theta_deg, "phi_deg": phi_deg, "temperatures_C": temperatures_C,
            "energy_J": energy_J, "currents_A": currents_A,
            "tracking_error_deg": tracking_error_deg, "target_theta_deg": target_theta_deg,
            "target_phi_deg": target_phi_deg, "energy_left_J": energy_left_J,
            "budget_exhausted": budget_exhausted}


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _target_spec(d: Mapping[str, Any]) -> TargetSpec:
    known = {f.name for f in fields(TargetSpec)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"targets: unknown field(s) {unknown}; known: {sorted(known)}")
    # JSON turns tuples into lists; the frozen spec keeps tuples (hashable, comparable)
    return TargetSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})
