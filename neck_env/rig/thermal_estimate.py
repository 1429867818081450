"""Spring temperatures and electrical energy from the currents the host commanded.

Most rigs have no thermistors on the springs. The observation still needs ``T1..T3`` (a policy
trained in simulation reads them), and the energy budget needs the springs' resistance, which
depends on their phase. :class:`ThermalEstimate` runs the simulator's own plant
(``neck_env.physics.plant``: Joule heating with the phase-dependent resistance, convection,
latent heat, phase kinetics) on the commanded currents, one rig, open loop. It is as good as
the model's convection coefficient and ambient temperature: refit those with ``neck_env.gap``
on the rig's recordings and pass the corrected parameters.

The hardware env feeds it the relay states read back in every telemetry sample (the supply
current while a relay is on, 0 A while off, held between samples), so the switching of the
firmware's duty windows is followed as it happened, not averaged.

Why the plant and not a separate lumped model: the resistance, latent heat and transformation
temperatures that set the springs' temperature are the ones the simulated env uses, so a
policy trained in simulation sees the same temperature trajectory for the same currents (the
head pose the plant also computes is ignored: the IMU measures it).
"""

from __future__ import annotations

import numpy as np

from ..params import NeckParams, default_params
from ..physics import layout as L
from ..physics.plant import SPRINGS_PER_MUSCLE, constants_from_params, initial_state, step_inplace

__all__ = ["ThermalEstimate"]

MAX_SUBSTEP_S = 0.05  # the plant's first-order step is accurate to ~0.4 deg at 50 ms


class ThermalEstimate:
    """Open-loop plant model of one rig driven by commanded currents."""

    def __init__(self, params: NeckParams | None = None, ambient_C: float | None = None) -> None:
        p = params or default_params()
        if ambient_C is not None:
            p = p.replace(source="rig ambient", thermal__ambient_C=float(ambient_C))
        self.params = p
        self._consts = np.ascontiguousarray(constants_from_params(p))
        self._out = np.empty((1, L.N_OUT))
        self._left = np.full(1, np.inf)
        self.reset()

    def reset(self) -> None:
        """Springs at ambient, martensite, head upright (a rig left to cool)."""
        self._x = initial_state(self._consts, 1)
        self.energy_J = 0.0

    @property
    def ambient_C(self) -> float:
        return float(self.params.thermal.ambient_C)

    @property
    def temperatures_C(self) -> np.ndarray:
        return self._x[0, L.S_T:L.S_T + 3].copy()

    def resistance_ohm(self) -> np.ndarray:
        """Present resistance of each muscle (its two springs in series), ohm."""
        xi = self._x[0, L.S_XI:L.S_XI + 3]
        c = self._consts[0]
        per_spring = c[L.R_M] * xi + c[L.R_A] * (1.0 - xi)
        return SPRINGS_PER_MUSCLE * per_spring

    def warm_up(self) -> None:
        """Compile the plant kernel (one step on a scratch copy; the estimate is unchanged)."""
        x = self._x.copy()
        step_inplace(self._consts, x, np.zeros((1, 3)), MAX_SUBSTEP_S, 1, self._left.copy(),
                     np.empty_like(self._out))

    def advance(self, rms_current_A: np.ndarray, dt_s: float) -> float:
        """Advance by ``dt_s`` with these RMS currents (3,); returns the energy spent, J."""
        cur = np.ascontiguousarray(np.asarray(rms_current_A, float).reshape(1, 3))
        if not np.all(np.isfinite(cur)) or np.any(cur < 0):
            raise ValueError(f"currents must be finite and >= 0, got {cur.ravel()}")
        if dt_s < 0:
            raise ValueError(f"dt_s must be >= 0, got {dt_s}")
        n = max(1, int(np.ceil(dt_s / MAX_SUBSTEP_S - 1e-9)))
        h = dt_s / n
        spent = 0.0
        for _ in range(n):
            if h <= 0:
                break
            step_inplace(self._consts, self._x, cur, h, 1, self._left, self._out)
            spent += float(self._out[0, L.O_POWER:L.O_POWER + 3].sum()) * h
        self.energy_J += spent
        return spent

    # -- across processes (``neck_env.rig.memory``) ------------------------------------------
    def state_vector(self) -> list[float]:
        """The plant state of the estimate, to be restored by :meth:`load_state_vector`."""
        return [float(v) for v in self._x[0]]

    def load_state_vector(self, values) -> None:
        """Restore a state saved by :meth:`state_vector` (raises ``ValueError`` if it does not
        fit this plant: another version of the model saved it)."""
        v = np.asarray(values, dtype=float)
        if v.shape != self._x[0].shape or not np.all(np.isfinite(v)):
            raise ValueError(f"saved thermal state has {v.size} values, this model needs "
                             f"{self._x.shape[1]} finite ones")
        self._x[0] = v
