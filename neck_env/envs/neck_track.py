"""NeckTrack-v0 / -v1: pose tracking with an SMA-actuated continuum neck under an energy budget."""

from __future__ import annotations

from typing import Any

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from gymnasium.vector.vector_env import AutoresetMode

from ..params import NeckParams, resolve_params
from ..sensors import SensorParams
from ..task import Task
from .core import NeckTrackCore, Randomization

_DOC = """
    ## Description

    A 2-DOF continuum neck (Das et al.): a TPU backbone bent by three SMA-spring muscles at
    azimuths 180, 60 and 300 deg. Heating a muscle's springs (Joule heating through relays from
    a DC supply) makes them contract once they pass the stress-shifted austenite start
    temperature; the head then bends toward that muscle. Cooling takes tens of seconds. The
    task: follow a moving target pose (waypoints reached by steps or ramps over 2-6 s, each
    segment lasting 8-20 s, tilt up to 25 deg toward a muscle and 18 deg between two -- the
    workspace reachable under the over-temperature cut) for 60 s with a fixed electrical
    energy budget.

    ## Action space

    | action_mode       | space                                | meaning                                   |
    |-------------------|--------------------------------------|-------------------------------------------|
    | `"current"` (default) | `Box(0, 8, (3,), float32)`       | current through muscle 1-3, A             |
    | `"relay"`         | `MultiBinary(3)`                     | relay k on: `supply_current_A` flows      |

    Both drive the same plant, through the `actuation` the task names (`neck_env.actuation`):
    `"ideal"` (v0's default): the commanded current flows steadily for the step; `"firmware"`
    (v1's default, and what `HardwareNeckEnv` on the rig does): a current becomes the duty
    `(I / I_s)^2` of the supply current in the firmware's 1 s windows, capped at 80 % (at most
    0.89 `I_s` = 6.26 A steady-equivalent at 7 A), and a relay held on is forced off after 10 s
    and locked out for 10 s, with the sustained-duty limiter beside it. Currents outside [0, 8] A are clipped to it (as Gymnasium's
    Box-action envs do); NaN/inf, a wrong shape, a non-numeric dtype or relay values other than
    0/1 raise `ValueError` (`neck_env.task.Task.currents_A`).

    ## Observation space

    `Box(float32, (8,))`, built by `neck_env.observation` exactly as the rig env builds it:

    | index | observation                                   | unit | min | max |
    |-------|-----------------------------------------------|------|-----|-----|
    | 0, 1  | measured head tilt vector theta (cos, sin) phi | deg  | -90 | 90  |
    | 2-4   | measured spring temperature, muscles 1-3       | degC | -40 | 300 |
    | 5, 6  | target tilt vector theta* (cos, sin) phi*      | deg  | -90 | 90  |
    | 7     | remaining fraction of the energy budget        | -    | 0   | 1   |

    Tilt comes from a simulated MPU6050 (per-episode bias, white noise, mount rotation if the
    `imu_misalignment` effect is on) through the rig's complementary filter; temperatures carry
    thermistor noise (`SensorParams`).

    ## Rewards

    `reward = -e`, with `e` the tracking error in degrees: the distance between the true head
    tilt vector `theta (cos phi, sin phi)` and the target's (within 2 % of the angle between
    actual and target head axes for tilts up to 30 deg; well defined upright). An episode of
    1200 steps that never moves scores about -1200 x (mean target tilt).

    ## Starting state

    Upright, springs at ambient temperature and fully martensite, target upright for the first
    2 s. `randomize=True` draws plant parameters per episode (`Randomization`); `effects`
    switches on unmodelled effects from `neck_env.effects` (a mapping name -> parameters is
    fixed; a list of names is sampled within ranges every episode).

    ## Episode end

    | condition                                | result             |
    |------------------------------------------|--------------------|
    | `episode_s` (60 s, 1200 steps) elapsed   | `truncated = True` |
    | no terminal state                        | `terminated` always False |

    When the energy budget is spent, actuation is cut (currents become 0) and the episode goes
    on: the head relaxes as the springs cool. A muscle whose spring is at or above `cutoff_C`
    (160 C) gets no current until it cools below it (the rig firmware's over-temperature cut;
    overheated Flexinol loses its memory).

    ## Info

    (`neck_env.task.INFO_KEYS`, the same keys on the rig.) `theta_deg`, `phi_deg` (true pose), `temperatures_C` (3,), `energy_J` (cumulative electrical
    energy this episode), `currents_A` (3,) (what flowed, after budget and supply limits),
    `tracking_error_deg`, `target_theta_deg`, `target_phi_deg`, `energy_left_J`,
    `budget_exhausted`.

    ## Arguments

    The task (`neck_env.task.Task`, its fields as keywords, or `task=Task(...)`):
    `action_mode`, `dt` (control period, 0.05 s), `episode_s` (60), `energy_budget_J` (1500;
    `float("inf")` for none), `supply_current_A` (7 A), `cutoff_C` (160), `targets`
    (`TargetSpec` or its fields as a dict), `actuation` (`"ideal"` or `"firmware"`: the one that
    matches the rig). The simulation: `params` (`NeckParams` or JSON
    path; default: the calibrated defaults), `sensors` (`SensorParams`), `randomize`,
    `effects`, and `render_mode` (`"rgb_array"`; `"human"` on the single env: a window,
    `render()` returns None).

    ## Version History

    * v1 (2026-11-27, no change to the default dynamics): `params` may give the springs a heat
      path into their terminals (`Thermal.terminal_*`, off in the calibrated defaults), as
      `neck-gap --fit-terminals` exports it for a rig whose crimps and posts take heat.
    * v1 (2026-11-24, no change to the default dynamics): the opt-in `sma_fatigue` effect keeps
      the recoverable strain it takes as permanent set, so a worn muscle bends less when hot
      and rests where it did; before, the lost strain vanished, the cold springs pulled harder
      and tilted the neck toward the worn muscle at rest (7 deg at 40 % loss).
    * v1: the energy budget binds a good controller and the actuation is the rig's
      (`neck_env.V1_KWARGS`: `energy_budget_J=900`, `actuation="firmware"`; both can still be
      overridden). The budget is chosen by a stated rule: the largest budget on a 100 J grid at
      which the PID's RMSE is at least 15 % worse than with no budget, measured on 30 episodes
      (seeds 1000-1029, 60 s, current mode, firmware actuation): unlimited 6.67 deg (956 J
      used), 1500 J 6.67, 1200 J 6.68, 1000 J 7.48 (+12 %), **900 J 8.37 (+26 %, budget spent
      in 16 of 30 episodes)**, 800 J 9.29. (Bang-bang on the same episodes: 6.51 unlimited,
      7.62 at 900 J.) At v0's 1500 J nothing binds (the PID uses ~960 J), so the budget decided
      nothing. The firmware actuation is what a policy meets on the rig: trained on v0's steady
      8 A, policies met duty windows and a 6.26 A ceiling there. Observation, reward, targets
      and episode length are v0's.
    * v0: initial version (1500 J, ideal actuation).
"""


def _build(num_envs, task, task_kwargs, params, sensors, randomize, effects) -> NeckTrackCore:
    if task is None:
        task = Task.from_kwargs(task_kwargs)
    elif task_kwargs:
        raise TypeError(f"give the task either as task=Task(...) or as keywords, not both "
                        f"(got task and {sorted(task_kwargs)})")
    elif not isinstance(task, Task):
        raise ValueError(f"task must be a neck_env.task.Task, got {type(task).__name__}")
    if sensors is not None and not isinstance(sensors, SensorParams):
        raise ValueError(f"sensors must be a SensorParams, got {type(sensors).__name__}")
    return NeckTrackCore(num_envs, task, resolve_params(params), sensors or SensorParams(),
                         randomize, effects)


class NeckTrackEnv(gym.Env):
    __doc__ = "Single NeckTrack environment.\n" + _DOC

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 20}

    def __init__(self, *, task: Task | None = None, params: NeckParams | str | None = None,
                 sensors: SensorParams | None = None, randomize: bool | Randomization = False,
                 effects=None, render_mode: str | None = None, **task_kwargs: Any):
        self.core = _build(1, task, task_kwargs, params, sensors, randomize, effects)
        self.task = self.core.task
        self.dt = self.task.dt
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.render_mode = render_mode
        self._renderer = None
        self._started = False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        # The core keeps its own generator per env: a seed reseeds it (drawn from our np_random,
        # as the vector env does per sub-env); without one it continues, as after an autoreset.
        core_seed = None if seed is None else int(self.np_random.integers(0, 2**63))
        self.core.reset(np.array([0]), [core_seed])
        self._started = True
        if self.render_mode == "human":
            self.render()
        return self.core.obs[0].copy(), self._info()

    def step(self, action):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        self.core.step(self.task.currents_A(action))
        if self.render_mode == "human":
            self.render()
        info = self._info()
        truncated = bool(self.core.episode_over(0))
        return self.core.obs[0].copy(), -info["tracking_error_deg"], False, truncated, info

    def _info(self) -> dict[str, Any]:
        return self.core.info(0)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode")
            return None
        from ..render import NeckRenderer

        if self._renderer is None:
            self._renderer = NeckRenderer(self.core.params, human=self.render_mode == "human")
        frame = self._renderer.draw(self.core, 0)
        # Gymnasium's contract: "human" shows the frame and returns None
        return None if self.render_mode == "human" else frame

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class NeckTrackVectorEnv(VectorEnv):
    __doc__ = ("Natively batched NeckTrack: one compiled step advances all `num_envs` rigs.\n"
               "Sub-env i reset with seed s gets seed s + i, so it reproduces a single env reset "
               "with seed s + i exactly. Autoreset: next step (Gymnasium's default).\n" + _DOC)

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, task: Task | None = None,
                 params: NeckParams | str | None = None, sensors: SensorParams | None = None,
                 randomize: bool | Randomization = False, effects=None,
                 render_mode: str | None = None, **task_kwargs: Any):
        self.core = _build(num_envs, task, task_kwargs, params, sensors, randomize, effects)
        self.task = self.core.task
        self.num_envs = self.core.n
        self.dt = self.task.dt
        self.single_action_space = self.task.action_space
        self.single_observation_space = self.task.observation_space
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              self.num_envs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.render_mode = render_mode
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._all = np.ones(self.num_envs, dtype=bool)
        self._no_term = np.zeros(self.num_envs, dtype=bool)
        self._renderer = None
        self._started = False

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        n = self.num_envs
        if seed is None:
            seeds = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed list must have {n} entries, got {len(seeds)}")
        # Same derivation as the single env: its np_random (seeded) draws the core's seed.
        core_seeds = []
        for s in seeds:
            if s is None:
                core_seeds.append(None)
            else:
                rng, _ = gym.utils.seeding.np_random(s)
                core_seeds.append(int(rng.integers(0, 2**63)))
        mask = None if options is None else options.get("reset_mask")
        ids = np.arange(n) if mask is None else np.nonzero(np.asarray(mask, bool))[0]
        self.core.reset(ids, [core_seeds[i] for i in ids])
        self._autoreset[ids] = False
        self._started = True
        return self.core.obs.copy(), self._info()

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        self.core.step(self.task.currents_A(actions, self.num_envs))
        truncated = self.core.truncated.copy()
        rewards = self.core.reward.copy()
        if self._autoreset.any():
            ids = np.nonzero(self._autoreset)[0]
            self.core.reset(ids, None)
            rewards[ids] = 0.0
            truncated[ids] = False
        self._autoreset = truncated.copy()
        return self.core.obs.copy(), rewards, self._no_term.copy(), truncated, self._info()

    def _info(self) -> dict[str, Any]:
        info = self.core.info()
        for k in list(info):
            info["_" + k] = self._all
        return info

    def render(self):
        if self.render_mode is None:
            return None
        from ..render import NeckRenderer

        if self._renderer is None:
            self._renderer = NeckRenderer(self.core.params, human=False)
        return self._renderer.draw(self.core, 0)

    def close_extras(self, **kwargs):
        self._renderer = None
