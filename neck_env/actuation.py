"""What the rig's firmware does to a command: the env option ``actuation="firmware"``.

The simulated envs have two actuation models (``Task.actuation``):

| option | a current command ``I`` (A) | a relay command (on/off) |
|---|---|---|
| ``"ideal"`` (``NeckTrack-v0``) | flows steadily for the whole step, 0-8 A | ``supply_current_A`` flows while on |
| ``"firmware"`` (``NeckTrack-v1``, and **what the rig does**) | ``HardwareNeckEnv`` sends duty ``(I / I_s)^2`` (``SET_DUTY``, permille); the firmware clamps it to 80 % and switches the relay on for the first ``duty`` ms of every 1000 ms window of its own clock, so the full supply current ``I_s`` flows in bursts and the steady-equivalent current is at most ``sqrt(0.8) I_s`` = 0.89 ``I_s`` | ``SET_RELAYS``: on until commanded off, but forced off after 10 s of continuous on-time and locked out for 10 s; a leaky bucket (+1 per ms on, -4 per ms off, capacity 20 s) forces a muscle off and refuses it until it has drained when the long-run duty exceeds 80 % |

``firmware_step`` reproduces ``muscles_update`` and the ``SET_DUTY`` / ``SET_RELAYS`` handlers of
``firmware/src/neck_fw.cpp`` at the firmware's 1 ms resolution and returns, per muscle, the
RMS current over the control step (``I_s sqrt(on_ms / step_ms)``: Joule heat goes with I^2,
and the ~20 s thermal time constant averages within a 50 ms step) -- the same figure the rig
env reports as ``info["currents_A"]``. The firmware's window phase at the start of an episode
(its ``millis()`` modulo 1000) is whatever it is on the rig; in simulation it is drawn per
episode. ``FirmwareLimits`` holds the firmware's numbers (``firmware/src/config.h``, also sent in
its HELLO reply; ``tests/test_actuation.py`` reads them from the source, the HIL tests from the
reply).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .physics.compile import jit

__all__ = ["ACTUATIONS", "FirmwareLimits", "FIRMWARE", "FW_STATE_DIM", "firmware_step",
           "firmware_reset", "max_equivalent_current_A"]

ACTUATIONS = ("ideal", "firmware")


@dataclass(frozen=True)
class FirmwareLimits:
    """The firmware's switching and safety numbers (``firmware/src/config.h``)."""

    duty_window_ms: int = 1000  # DUTY_WINDOW_MS
    duty_max_permille: int = 800  # DUTY_MAX_PERMILLE
    ontime_cap_ms: int = 10000  # ONTIME_CAP_MS
    lockout_ms: int = 10000  # LOCKOUT_MS
    duty_bucket_cap_ms: int = 20000  # DUTY_BUCKET_CAP_MS
    duty_bucket_drain: int = 4  # DUTY_BUCKET_DRAIN

    def as_array(self) -> np.ndarray:
        return np.array([self.duty_window_ms, self.duty_max_permille, self.ontime_cap_ms,
                         self.lockout_ms, self.duty_bucket_cap_ms, self.duty_bucket_drain],
                        dtype=np.float64)


FIRMWARE = FirmwareLimits()

# Per-muscle firmware state columns (float64 so one array carries them into the kernel).
FW_MODE = 0  # 0 off, 1 direct (SET_RELAYS), 2 duty (SET_DUTY)
FW_DUTY = 1  # permille applied (after the clamp)
FW_ON = 2  # output state, 0/1
FW_ON_SINCE = 3  # ms (firmware clock) the output last went on
FW_LOCKED = 4
FW_LOCK_UNTIL = 5  # ms
FW_BUCKET = 6  # ms-equivalents
FW_TRIP = 7  # bucket trip: held off until the bucket is empty
FW_STATE_DIM = 8
_OFF, _DIRECT, _DUTY = 0.0, 1.0, 2.0


def max_equivalent_current_A(supply_current_A: float, limits: FirmwareLimits = FIRMWARE) -> float:
    """Largest steady-equivalent current ``SET_DUTY`` can give: ``sqrt(duty cap) I_s``."""
    return float(supply_current_A * np.sqrt(limits.duty_max_permille / 1000.0))


def firmware_reset(state: np.ndarray) -> None:
    """All muscles off, unlocked, bucket empty (the rig starts an episode at rest)."""
    state[...] = 0.0


@jit
def firmware_step(state, clock_ms, cmd_A, relay, supply_A, step_ms, lim, out_A):
    """One control step of the firmware for one rig.

    ``state`` (3, FW_STATE_DIM) is updated in place; ``clock_ms`` is the firmware's clock at the
    command (ms); ``cmd_A`` (3,) the host's command: currents (duty ``(I/I_s)^2`` in permille,
    rounded, as ``HardwareNeckEnv`` sends it) or, with ``relay``, on where > 0. Writes the RMS
    current of each muscle over the ``step_ms`` ms into ``out_A``; returns the refused mask
    (bit k: muscle k was commanded on while held off, as the ACK reports).
    """
    window, duty_max, ontime_cap, lockout = lim[0], lim[1], lim[2], lim[3]
    bucket_cap, drain = lim[4], lim[5]
    refused = 0
    # the command handler (SET_RELAYS / SET_DUTY)
    for k in range(3):
        blocked = state[k, FW_LOCKED] > 0 or state[k, FW_TRIP] > 0
        if relay:
            if cmd_A[k] > 0.0:
                if blocked:
                    refused |= 1 << k
                    state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
                else:
                    state[k, FW_MODE], state[k, FW_DUTY] = _DIRECT, 1000.0
            else:
                state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
        else:
            r = min(max(cmd_A[k] / supply_A, 0.0), 1.0)
            d = float(np.floor(1000.0 * r * r + 0.5))  # HardwareNeckEnv: int(round(1000 d))
            d = min(d, duty_max)
            if d == 0.0:
                state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
            elif blocked:
                refused |= 1 << k
                state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
            else:
                state[k, FW_MODE], state[k, FW_DUTY] = _DUTY, d
    # muscles_update once per ms of the step, the first right after the command (the pins
    # switch before the ACK); each integrates the 1 ms since the previous pass, and the output
    # it sets holds over [t, t + 1) ms.
    # on-time per muscle is counted in out_A (no allocation per rig and step in the hot loop)
    for k in range(3):
        out_A[k] = 0.0
    n = int(step_ms)
    dt = 1.0
    for tick in range(n):
        now = clock_ms + tick
        win_pos = now % window
        for k in range(3):
            if state[k, FW_ON] > 0:
                state[k, FW_BUCKET] += dt
            else:
                state[k, FW_BUCKET] = max(state[k, FW_BUCKET] - drain * dt, 0.0)
            if state[k, FW_TRIP] > 0 and state[k, FW_BUCKET] == 0.0:
                state[k, FW_TRIP] = 0.0
            if state[k, FW_LOCKED] > 0 and now >= state[k, FW_LOCK_UNTIL]:
                state[k, FW_LOCKED] = 0.0
            mode = state[k, FW_MODE]
            want = mode == _DIRECT or (mode == _DUTY and win_pos < state[k, FW_DUTY])
            if want and state[k, FW_ON] > 0:
                if now - state[k, FW_ON_SINCE] >= ontime_cap:
                    state[k, FW_LOCKED] = 1.0
                    state[k, FW_LOCK_UNTIL] = now + lockout
                    state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
                    want = False
                elif state[k, FW_BUCKET] >= bucket_cap:
                    state[k, FW_TRIP] = 1.0
                    state[k, FW_MODE], state[k, FW_DUTY] = _OFF, 0.0
                    want = False
            if state[k, FW_LOCKED] > 0 or state[k, FW_TRIP] > 0:
                want = False
            if want and state[k, FW_ON] == 0:
                state[k, FW_ON_SINCE] = now
            state[k, FW_ON] = 1.0 if want else 0.0
            if want:
                out_A[k] += 1.0
    for k in range(3):
        out_A[k] = supply_A * np.sqrt(out_A[k] / max(n, 1))
    return refused
