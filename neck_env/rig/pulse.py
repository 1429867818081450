"""The paper's step experiment on the rig: one muscle at a fixed current for some seconds, then
cooling, recorded (docs/recording-format.md) for ``neck-gap`` or a comparison with the simulator.

It runs through :class:`~neck_env.rig.hardware_env.HardwareNeckEnv` in relay mode, so the
pulse gets the same safety (all relays off on any error or Ctrl-C), recording, pacing and
thermal estimate as an episode. The bench supply sets the current: set it to ``current_A``
before starting; the recording's ``i_k`` is that setpoint while the relay is on.

A pulse starts at rest (``neck_env.experiments.REST``): the env waits, relays off, until the
springs are back near ambient -- measured, or estimated with the heating of earlier commands
on the same port (``neck_env.rig.memory``) -- and the tilt is steady; a neck that does not come
to rest within ``REST.timeout_s`` is an error, not a pulse from a bent start.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..experiments import REST
from ..targets import TargetSpec
from .hardware_env import HardwareNeckEnv
from .link import RigLink

__all__ = ["PulseResult", "run_pulse"]


@dataclass(frozen=True)
class PulseResult:
    """Summary of one pulse (the full series is in the recording)."""

    muscle: int  # 1-based, as in the paper and the recording columns
    current_A: float
    on_s: float
    cool_s: float
    max_theta_deg: float  # measured, over this pulse and its cooling
    t_max_s: float  # time of the maximum after the pulse started
    phi_at_max_deg: float
    max_temperature_C: float  # observed (thermistor or estimate) of the pulsed muscle
    energy_J: float
    recording: Path | None
    start_theta_deg: float = 0.0  # measured tilt when the pulse started (at rest: the IMU's rest reading)
    rested_s: float = 0.0  # waited for rest before the pulse


def run_pulse(link: RigLink, muscle: int, current_A: float, on_s: float = 5.0,
              cool_s: float = 25.0, record_dir: str | Path | None = None,
              thermistors: int = 0, ambient_C: float | None = None, params=None,
              cooldown: bool = True, dt: float = 0.05,
              say: Callable[[str], None] | None = None) -> PulseResult:
    """Relay ``muscle`` (1..3) on for ``on_s`` at the supply's ``current_A``, then off for
    ``cool_s``; returns the summary. Raises ``ValueError`` for arguments the rig cannot do
    (more than the firmware's continuous on-time cap, a muscle that does not exist)."""
    if muscle not in (1, 2, 3):
        raise ValueError(f"muscle must be 1, 2 or 3 (azimuth 180, 60, 300 deg), got {muscle!r}")
    if not (np.isfinite(on_s) and on_s > 0):
        raise ValueError(f"on_s must be > 0 s, got {on_s!r}")
    if not (np.isfinite(cool_s) and cool_s >= 0):
        raise ValueError(f"cool_s must be >= 0 s, got {cool_s!r}")
    cap_s = link.hello.ontime_cap_ms / 1000.0 if link.hello else 10.0
    if on_s >= cap_s:
        raise ValueError(f"on_s = {on_s} s reaches the firmware's continuous on-time cap of "
                         f"{cap_s:.0f} s (it would cut the relay and lock the muscle out)")
    total = on_s + cool_s
    # the target plays no part: keep it upright for the whole run
    env = HardwareNeckEnv(link=link, action_mode="relay", supply_current_A=current_A,
                          energy_budget_J=float("inf"), episode_s=total, dt=dt,
                          targets=TargetSpec(first_hold_s=total + 1.0), thermistors=thermistors,
                          ambient_C=ambient_C, params=params, record_dir=record_dir,
                          cooldown_s=REST.timeout_s if cooldown else 0.0, say=say)
    if say is not None and env.memory_note:
        say(env.memory_note)
    on = np.zeros(3, dtype=np.int8)
    on[muscle - 1] = 1
    off = np.zeros(3, dtype=np.int8)
    _, info0 = env.reset(seed=0, options={"require_rest": cooldown})
    rested = env.last_rest.waited_s if env.last_rest is not None else 0.0
    theta, phi, temp = [], [], []
    info: dict = {}
    for _ in range(env.task.episode_steps):
        # the springs heat in real time: on the host's clock from the "on" command
        # (``schedule_s``), so neither a stalled step nor a slow first one changes the hold
        _, _, _, _, info = env.step(on if env.schedule_s() < on_s else off)
        theta.append(info["theta_deg"])
        phi.append(info["phi_deg"])
        temp.append(float(info["temperatures_C"][muscle - 1]))
    rec = env.recordings[-1] if getattr(env, "recordings", None) else None
    i = int(np.argmax(theta))
    result = PulseResult(muscle, float(current_A), float(on_s), float(cool_s),
                         float(theta[i]), (i + 1) * env.dt, float(phi[i]), float(max(temp)),
                         float(info.get("energy_J", 0.0)), rec, float(info0["theta_deg"]), rested)
    return result
