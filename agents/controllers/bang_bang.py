"""Bang-bang control with hysteresis, per muscle, on the projected tilt error.

For muscle k with unit direction u_k (azimuth 180, 60, 300 deg) the projected error is
``p_k = (target - measured tilt) . u_k`` (deg): positive when the head should move toward that
muscle. A muscle's relay switches **on** when ``p_k > on_above_deg`` and **off** when
``p_k < off_below_deg``; in between it keeps its state (the hysteresis band suppresses
chattering on IMU noise). An overshoot makes the error project positively on the opposite
muscles, which then pull back (antagonistic action, the only fast way back: cooling takes
~20 s).

Temperature cap (springs burn): a muscle whose measured temperature reaches ``temp_cap_C``
switches off and may switch on again only below ``temp_cap_C - temp_band_C``.

"On" is ``on_current_A`` (default: the relay supply current, 7 A) in current mode and the relay
in relay mode, so both modes run the same law. The base class's energy-pacing governor still
applies (in current mode it scales the on-current down, in relay mode the duty).
"""

from __future__ import annotations

import numpy as np

from .allocation import muscle_unit_vectors
from .base import OBS_TARGET, OBS_TEMPS, OBS_TILT, Controller, over_temperature


class BangBangController(Controller):
    name = "bang_bang"
    thermal_limit = False  # its own on/off temperature hysteresis instead

    def __init__(self, task=None, *, on_above_deg: float = 1.0, off_below_deg: float = 0.0,
                 on_current_A: float | None = None, temp_band_C: float = 10.0, **kw):
        super().__init__(task, **kw)
        if not on_above_deg >= off_below_deg:
            raise ValueError("need on_above_deg >= off_below_deg (a hysteresis band)")
        self.on_above_deg = float(on_above_deg)
        self.off_below_deg = float(off_below_deg)
        self.on_current_A = min(float(on_current_A if on_current_A is not None
                                      else self.task.supply_current_A), self.i_max)
        self.temp_band_C = float(temp_band_C)
        self.u = muscle_unit_vectors(self.params.muscles.azimuths_deg)
        self.on = np.zeros(3, dtype=bool)
        self.too_hot = np.zeros(3, dtype=bool)

    def _reset(self, seed):
        self.on[:] = False
        self.too_hot[:] = False

    def _demand(self, obs):
        p = self.u @ (obs[OBS_TARGET] - obs[OBS_TILT])
        self.on = np.where(p > self.on_above_deg, True, np.where(p < self.off_below_deg, False, self.on))
        T = obs[OBS_TEMPS]
        self.too_hot = over_temperature(T, self.too_hot, self.temp_cap_C, self.temp_band_C)
        return np.where(self.on & ~self.too_hot, self.on_current_A, 0.0)
