"""NeckTrack-v0: pose tracking with an SMA-actuated continuum neck under an energy budget."""

from __future__ import annotations

from typing import Any

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from gymnasium.vector.vector_env import AutoresetMode

from ..observation import observation_space
from ..params import NeckParams
from ..physics import layout as L
from ..sensors import SensorParams
from ..targets import TargetSpec
from .core import (A_ERR, A_LEFT, A_TIDX, A_TPHI, A_TTHETA, A_USED, DEFAULT_BUDGET_J,
                   DEFAULT_CUTOFF_C, DEFAULT_DT_S, DEFAULT_EPISODE_S, DEFAULT_SUPPLY_A, MAX_CURRENT_A, NeckTrackCore,
                   Randomization, TaskConfig, resolve_params, validate_action)

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

    Both drive the same plant. NaN/inf, a wrong shape, currents outside [0, 8] A or relay values
    other than 0/1 raise `ValueError` (nothing is clipped).

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

    `theta_deg`, `phi_deg` (true pose), `temperatures_C` (3,), `energy_J` (cumulative electrical
    energy this episode), `currents_A` (3,) (what flowed, after budget and supply limits),
    `tracking_error_deg`, `target_theta_deg`, `target_phi_deg`, `energy_left_J`,
    `budget_exhausted`.

    ## Arguments

    `action_mode`, `dt` (control period, 0.05 s), `episode_s` (60), `energy_budget_J` (1500;
    `float("inf")` for none), `supply_current_A` (7 A), `cutoff_C` (160), `params`
    (`NeckParams` or JSON path;
    default: the calibrated defaults), `sensors` (`SensorParams`), `targets` (`TargetSpec`),
    `randomize`, `effects`, `render_mode` (`"rgb_array"` or `"human"`).
"""


def _build(num_envs, action_mode, dt, episode_s, energy_budget_J, supply_current_A, cutoff_C,
           params, sensors, targets, randomize, effects) -> NeckTrackCore:
    task = TaskConfig(action_mode=action_mode, dt=dt, episode_s=episode_s,
                      energy_budget_J=energy_budget_J, supply_current_A=supply_current_A,
                      cutoff_C=cutoff_C, targets=targets if targets is not None else TargetSpec())
    if sensors is not None and not isinstance(sensors, SensorParams):
        raise ValueError(f"sensors must be a SensorParams, got {type(sensors).__name__}")
    return NeckTrackCore(num_envs, task, resolve_params(params), sensors or SensorParams(),
                         randomize, effects)


def _action_space(mode: str) -> spaces.Space:
    if mode == "relay":
        return spaces.MultiBinary(3)
    return spaces.Box(0.0, MAX_CURRENT_A, (3,), dtype=np.float32)


class NeckTrackEnv(gym.Env):
    __doc__ = "Single NeckTrack environment.\n" + _DOC

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 20}

    def __init__(self, action_mode: str = "current", dt: float = DEFAULT_DT_S,
                 episode_s: float = DEFAULT_EPISODE_S, energy_budget_J: float = DEFAULT_BUDGET_J,
                 supply_current_A: float = DEFAULT_SUPPLY_A, cutoff_C: float = DEFAULT_CUTOFF_C,
                 params: NeckParams | str | None = None, sensors: SensorParams | None = None,
                 targets: TargetSpec | None = None, randomize: bool | Randomization = False,
                 effects=None, render_mode: str | None = None):
        self.core = _build(1, action_mode, dt, episode_s, energy_budget_J, supply_current_A,
                           cutoff_C, params, sensors, targets, randomize, effects)
        self.task = self.core.task
        self.dt = self.task.dt
        self.action_space = _action_space(action_mode)
        self.observation_space = observation_space()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.render_mode = render_mode
        self._scale = self.task.supply_current_A if action_mode == "relay" else 1.0
        self._steps = self.task.episode_steps
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
        cur = validate_action(action, self.task.action_mode, 1, single=True)
        self.core.step(cur * self._scale if self._scale != 1.0 else cur)
        if self.render_mode == "human":
            self.render()
        info = self._info()
        truncated = self.core.aux[0, A_TIDX] >= self._steps
        return self.core.obs[0].copy(), -info["tracking_error_deg"], False, bool(truncated), info

    def _info(self) -> dict[str, Any]:
        c = self.core
        theta, phi = c.out[0, L.O_THETA:L.O_PHI + 1].tolist()
        a = c.aux[0].tolist()
        left = a[A_LEFT]
        return {
            "theta_deg": theta,
            "phi_deg": phi,
            "temperatures_C": c.x[0, L.S_T:L.S_T + 3].copy(),
            "energy_J": a[A_USED],
            "currents_A": c.out[0, L.O_CURRENT:L.O_CURRENT + 3].copy(),
            "tracking_error_deg": a[A_ERR],
            "target_theta_deg": a[A_TTHETA],
            "target_phi_deg": a[A_TPHI],
            "energy_left_J": left,
            "budget_exhausted": left <= 0.0,
        }

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode")
            return None
        from ..render import NeckRenderer

        if self._renderer is None:
            self._renderer = NeckRenderer(self.core.params, human=self.render_mode == "human")
        return self._renderer.draw(self.core, 0)

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

    def __init__(self, num_envs: int = 1, action_mode: str = "current", dt: float = DEFAULT_DT_S,
                 episode_s: float = DEFAULT_EPISODE_S, energy_budget_J: float = DEFAULT_BUDGET_J,
                 supply_current_A: float = DEFAULT_SUPPLY_A, cutoff_C: float = DEFAULT_CUTOFF_C,
                 params: NeckParams | str | None = None,
                 sensors: SensorParams | None = None, targets: TargetSpec | None = None,
                 randomize: bool | Randomization = False, effects=None,
                 render_mode: str | None = None):
        self.core = _build(num_envs, action_mode, dt, episode_s, energy_budget_J,
                           supply_current_A, cutoff_C, params, sensors, targets, randomize, effects)
        self.task = self.core.task
        self.num_envs = self.core.n
        self.dt = self.task.dt
        self.single_action_space = _action_space(action_mode)
        self.single_observation_space = observation_space()
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              self.num_envs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.render_mode = render_mode
        self._scale = self.task.supply_current_A if action_mode == "relay" else 1.0
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
        cur = validate_action(actions, self.task.action_mode, self.num_envs, single=False) * self._scale
        self.core.step(cur)
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
        c = self.core
        # One fresh array holds every value; the info entries are views into it, so nothing a
        # caller keeps aliases the env's buffers.
        rep = np.empty((self.num_envs, 14))
        rep[:, 0:2] = c.out[:, L.O_THETA:L.O_PHI + 1]
        rep[:, 2:5] = c.x[:, L.S_T:L.S_T + 3]
        rep[:, 5] = c.aux[:, A_USED]
        rep[:, 6:9] = c.out[:, L.O_CURRENT:L.O_CURRENT + 3]
        rep[:, 9] = c.aux[:, A_ERR]
        rep[:, 10:12] = c.aux[:, A_TTHETA:A_TPHI + 1]
        rep[:, 12] = c.aux[:, A_LEFT]
        left = rep[:, 12]
        info = {
            "theta_deg": rep[:, 0],
            "phi_deg": rep[:, 1],
            "temperatures_C": rep[:, 2:5],
            "energy_J": rep[:, 5],
            "currents_A": rep[:, 6:9],
            "tracking_error_deg": rep[:, 9],
            "target_theta_deg": rep[:, 10],
            "target_phi_deg": rep[:, 11],
            "energy_left_J": left,
            "budget_exhausted": left <= 0.0,
        }
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
