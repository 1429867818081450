"""Hand-written and model-based controllers for NeckTrack-v0 (one env, numpy in, numpy out).

| name        | module        | kind        | what it does                                                  |
|-------------|---------------|-------------|---------------------------------------------------------------|
| `zero`      | `base`        | heuristic   | reference: never heats                                        |
| `full_on`   | `base`        | heuristic   | reference: every muscle at full current (what the budget is for) |
| `open_loop` | `open_loop`   | heuristic   | inverse static map target -> steady currents, no feedback     |
| `open_loop_lead` | `open_loop` | heuristic | the same map, reached faster through an internal thermal model (still no feedback) |
| `bang_bang` | `bang_bang`   | heuristic   | relay per muscle on the projected tilt error, hysteresis band |
| `pid`       | `pid`         | heuristic   | PID on the tilt vector -> static-map allocation -> temperature loop |
| `mpc`       | `mpc`         | model-based | sampling MPC over the compiled simulator, open-loop state estimate |

Shared pieces: ``allocation`` (bending vector -> non-negative muscle pulls), ``static_map``
(simulated steady states and their inverse), ``base`` (task description, act() pipeline,
thermal cap, energy pacing, relay modulation).

    from agents.controllers import make_controller
    ctrl = make_controller("pid", {"action_mode": "relay"})
    ctrl.reset(); action = ctrl.act(obs)
"""

from __future__ import annotations

from typing import Any, Mapping

from .base import ControlTask, Controller, FullOnController, ZeroController
from .bang_bang import BangBangController
from .mpc import MPCController
from .open_loop import OpenLoopController, OpenLoopLeadController
from .pid import PIDController

CONTROLLERS: dict[str, type[Controller]] = {
    "zero": ZeroController,
    "full_on": FullOnController,
    "open_loop": OpenLoopController,
    "open_loop_lead": OpenLoopLeadController,
    "bang_bang": BangBangController,
    "pid": PIDController,
    "mpc": MPCController,
}


def make_controller(name: str, task: ControlTask | Mapping[str, Any] | None = None,
                    **options: Any) -> Controller:
    """A controller by name for a task (``ControlTask``, env kwargs, or None = env defaults)."""
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; known: {sorted(CONTROLLERS)}")
    return CONTROLLERS[name](task, **options)


__all__ = ["CONTROLLERS", "ControlTask", "Controller", "make_controller", "BangBangController",
           "FullOnController", "MPCController", "OpenLoopController",
           "OpenLoopLeadController", "PIDController",
           "ZeroController"]
