"""Open-loop control: the inverse static map, no feedback.

``currents = map.currents_for(target)``: the steady currents that, held long enough, settle the
calibrated plant at the target tilt (``static_map.SteadyStateMap``: simulated steady states on
a grid of constant currents through two adjacent muscles, inverted by direction, with the
pair bracketing the target direction sharing it; a target along a muscle goes to that muscle).
It reads only the target (obs[5:7]) and the energy fraction; never the tilt or the temperatures
(the base class's thermal limit does read the temperatures -- a safety interlock, not control;
at steady currents it never binds, since the map leaves out currents that settle above the cap).

``lead_tau_s`` (default None = pure static map): optionally speed the thermal response up with
an internal, unmeasured first-order thermal model of each muscle: the command is the power that
would bring the *modelled* spring temperature to the map's steady temperature with this time
constant (then holds the steady power). Still open loop: the model runs on the commanded
currents only.

Why it tracks poorly: the steady state takes ~1 min to reach at steady currents (thermal time
constant ~22 s, and the transformation sits at the top of the heating curve), the targets
change every 4-12 s, the map is the heating branch (a tilt approached from above holds at lower
currents), and the IMU never closes the loop.
"""

from __future__ import annotations

import numpy as np

from .base import OBS_TARGET, Controller
from .static_map import steady_state_map


class OpenLoopController(Controller):
    name = "open_loop"

    def __init__(self, task=None, *, lead_tau_s: float | None = None, **kw):
        super().__init__(task, **kw)
        self.map = steady_state_map(self.params, self.temp_cap_C)
        self.lead_tau_s = lead_tau_s
        self._T_model = np.full(3, self.thermal.ambient_C)

    def _reset(self, seed):
        self._T_model = np.full(3, self.thermal.ambient_C)

    def _demand(self, obs):
        if self.steps == 0:
            self._T_model[:] = self.ambient_C
        steady = self.map.currents_for(obs[OBS_TARGET])
        if self.lead_tau_s is None:
            return steady
        T_set = self.map.steady_temperature_for(steady)
        p = self.thermal.power_to_reach(T_set, self._T_model, self.lead_tau_s, self.ambient_C)
        return np.minimum(self.thermal.current_for_power(p), self.i_max)

    def _applied(self, obs, currents):
        # Advance the internal thermal model on what was commanded (exact for constant power).
        th = self.thermal
        p = th.power_of_current(currents)
        T_inf = self.ambient_C + p / th.convection_W_K
        self._T_model = T_inf + (self._T_model - T_inf) * np.exp(-self.dt / th.time_constant_s)


class OpenLoopLeadController(OpenLoopController):
    """``OpenLoopController`` with the thermal lead on (``lead_tau_s`` = 0.5 s by default)."""

    name = "open_loop_lead"

    def __init__(self, task=None, *, lead_tau_s: float | None = 0.5, **kw):
        super().__init__(task, lead_tau_s=lead_tau_s, **kw)
