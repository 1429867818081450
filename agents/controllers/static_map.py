"""Steady-state (static) map of the calibrated plant and its inverse: target tilt -> currents.

Built by simulation, not by formula: constant currents through two adjacent muscles on a grid
(the third muscle cold) are run to steady state from a cold, upright neck with the compiled
plant (``neck_env.physics.plant.step_inplace``, all grid points batched), and the settled tilt
vectors are tabulated. Two muscles, not one, because they interact: a muscle pulling alone at
2.75 A settles at 20.4 deg, but two adjacent muscles at 2.75 A each settle at 12.6 deg
between them, not the 20.4 deg the vector sum of the single-muscle tilts predicts (each one
stretches the other and the cold third muscle; figures from the calibrated defaults).

The inverse is a table over target tilt theta* (deg) and direction within the pair's 120 deg
sector: for each entry the grid pair of currents whose steady tilt is nearest, with a small
penalty on electrical power so that the cheapest of near-equal solutions wins (two muscles
fighting each other reach the same tilt at a higher cost). ``currents_for(target)`` looks the
table up (bilinear). Currents whose steady spring temperature exceeds ``temp_cap_C`` are left
out of the grid, so targets beyond what the capped springs reach map to the nearest reachable.

Reach under a temperature cap (calibrated defaults, steady state, heating branch): with springs
at most 150 C the head settles at up to 31.6 deg toward a muscle but only ~20 deg midway
between two (they pull 120 deg apart and stretch each other and the third); 25 deg midway needs
~170-175 C (cap 160 C: ~22.5 deg, 170 C: ~24-25 deg, 180 C: ~29 deg). The task's targets go up to
25 deg in every direction, so with a 150 C cap some of them are out of reach for any controller
(``max_reach_deg()``).

All of this is the *heating-branch* steady state (reached from cold). SMA hysteresis means a
tilt approached from above settles at a lower temperature; a static map cannot know the
history, which is why the open-loop controller built on it is only a baseline.

Cost: ~1 s at construction (~1100 rigs over 300 s of simulated time at 0.25 s steps, batched
in chunks of 500 on the plant's serial path), cached per (parameters, cap) within the process.
"""

from __future__ import annotations

import math

import numpy as np

from neck_env.params import NeckParams, default_params
from neck_env.physics import layout as L
from neck_env.physics.plant import constants_from_params, initial_state, step_inplace

# Current grid (A): 0, 1, 1.5, then 1.8 A (below it the springs settle short of the
# stress-shifted austenite start: < 1.3 deg) in 0.05 A steps up to ~10 C above the cap.
_SETTLE_S = 300.0  # ~14 thermal time constants
_SIM_DT_S = 0.25  # steady tilts within 0.03 deg of 400 s at 0.2 s (checked on the defaults)
_CHUNK = 500  # rigs per call: stays on the plant's serial path (its threads start at 512)
_THETA_STEP_DEG = 0.5
_DIR_STEP_DEG = 2.0
_POWER_WEIGHT = 0.02  # deg^2 per W: tie-breaker toward the cheaper of near-equal solutions
_UPSAMPLE = 2  # the forward map is interpolated this much finer before the inverse search


class SteadyStateMap:
    """Steady tilt of the plant under constant currents and its inverse (see module doc)."""

    def __init__(self, params: NeckParams | None = None, temp_cap_C: float = 150.0):
        self.params = params if params is not None else default_params()
        self.temp_cap_C = float(temp_cap_C)
        az = np.mod(np.asarray(self.params.muscles.azimuths_deg, dtype=float), 360.0)
        self.azimuths_deg = az
        self._order = np.argsort(az)
        spans = [(az[self._order[(j + 1) % 3]] - az[self._order[j]]) % 360.0 for j in range(3)]
        self._spans = np.array(spans)
        self.symmetric = bool(np.allclose(self._spans, 120.0, atol=1e-9))
        c = constants_from_params(self.params)
        self._consts = c
        self.muscle_resistance_ohm = 2 * c[0, L.R_A]  # hot (austenite), both springs in series
        self._build()

    # -- forward map --------------------------------------------------------------------------
    def _build(self) -> None:
        c0 = self._consts[0]
        # Grid up to the current whose steady temperature is ~10 C above the cap (hot-spring
        # resistance, no latent heat: T_ss - T_amb = I^2 R / hA per spring).
        i_top = math.sqrt((self.temp_cap_C + 10.0 - c0[L.AMBIENT]) * c0[L.HA] / c0[L.R_A])
        g = np.concatenate([[0.0, 1.0, 1.5], np.round(np.arange(1.8, i_top + 0.05, 0.05), 4)])
        n = g.size
        pairs = [(self._order[j], self._order[(j + 1) % 3]) for j in range(3)]
        use = pairs[:1] if self.symmetric else pairs
        cur = np.zeros((len(use), n, n, 3))
        for p, (a, b) in enumerate(use):
            cur[p, :, :, a] = g[:, None]
            cur[p, :, :, b] = g[None, :]
        rigs = np.ascontiguousarray(cur.reshape(-1, 3))
        state, out = settle(self._consts, rigs)
        theta, phi = out[:, L.O_THETA], np.radians(out[:, L.O_PHI])
        vec = np.stack([theta * np.cos(phi), theta * np.sin(phi)], axis=1)  # tilt vector, deg
        temps = state[:, L.S_T:L.S_T + 3].reshape(len(use), n, n, 3)
        vec = vec.reshape(len(use), n, n, 2)
        # Local frame of each pair: muscle a along +x, muscle b at +span.
        self.grid_A = g
        self.local_maps = []
        for p, (a, b) in enumerate(use):
            rot = -math.radians(self.azimuths_deg[a])
            cr, sr = math.cos(rot), math.sin(rot)
            v = vec[p]
            local = np.stack([cr * v[..., 0] - sr * v[..., 1], sr * v[..., 0] + cr * v[..., 1]], -1)
            self.local_maps.append(local)
        # Steady spring temperature of a muscle vs its own current (the other muscle barely
        # changes it: < 1.5 C across the grid).
        a0 = use[0][0]
        self.steady_T_C = temps[0, :, 0, a0].copy()
        self.steady_theta_deg = np.hypot(*vec[0, :, 0, :].T)  # single muscle, deg
        self._build_inverse()

    def _allowed(self) -> np.ndarray:
        return self.steady_T_C <= self.temp_cap_C

    def _build_inverse(self) -> None:
        g = self.grid_A
        ok = self._allowed()
        fine = np.interp(np.linspace(0, ok.sum() - 1, (ok.sum() - 1) * _UPSAMPLE + 1),
                         np.arange(ok.sum()), g[ok])
        self._theta_axis = np.arange(0.0, 35.0 + 1e-9, _THETA_STEP_DEG)
        self.tables = []
        self.reach_deg = []
        for p, local in enumerate(self.local_maps if not self.symmetric else self.local_maps[:1]):
            span = self._spans[p]
            dirs = np.arange(0.0, span + 1e-9, _DIR_STEP_DEG)
            m = local[np.ix_(ok, ok)]
            fm = _interp2(m, np.arange(ok.sum()), fine_index(ok.sum()))
            ia, ib = np.meshgrid(fine, fine, indexing="ij")
            power = self.muscle_resistance_ohm * (ia ** 2 + ib ** 2)
            cand = fm.reshape(-1, 2)
            pw = power.ravel()
            th, dr = np.meshgrid(self._theta_axis, np.radians(dirs), indexing="ij")
            want = np.stack([th * np.cos(dr), th * np.sin(dr)], -1).reshape(-1, 2)
            table = np.empty((want.shape[0], 2))
            for s in range(0, want.shape[0], 512):
                w = want[s:s + 512]
                d2 = ((cand[None, :, :] - w[:, None, :]) ** 2).sum(-1) + _POWER_WEIGHT * pw[None]
                k = d2.argmin(1)
                table[s:s + 512, 0] = ia.ravel()[k]
                table[s:s + 512, 1] = ib.ravel()[k]
            self.tables.append((dirs, table.reshape(th.shape + (2,))))
            # farthest reachable tilt per direction (for reporting)
            reach = []
            for d in np.radians(dirs):
                proj = cand @ np.array([math.cos(d), math.sin(d)])
                perp = np.abs(cand @ np.array([-math.sin(d), math.cos(d)]))
                sel = perp < 1.0
                reach.append(proj[sel].max() if sel.any() else 0.0)
            self.reach_deg.append(np.array(reach))

    # -- inverse -------------------------------------------------------------------------------
    def currents_for(self, target_vec) -> np.ndarray:
        """Steady currents (3,) in A that hold the head at tilt vector ``target_vec`` (deg)."""
        v = np.asarray(target_vec, dtype=float).reshape(2)
        out = np.zeros(3)
        theta = math.hypot(v[0], v[1])
        if theta < 1e-9:
            return out
        direction = math.degrees(math.atan2(v[1], v[0])) % 360.0
        for j in range(3):
            a, b = self._order[j], self._order[(j + 1) % 3]
            rel = (direction - self.azimuths_deg[a]) % 360.0
            if rel <= self._spans[j] + 1e-9:
                dirs, table = self.tables[0 if self.symmetric else j]
                ia, ib = _bilinear(table, self._theta_axis, dirs, theta, rel)
                out[a], out[b] = ia, ib
                return out
        return out

    def steady_temperature_for(self, currents_A) -> np.ndarray:
        """Steady spring temperature (deg C) of a muscle driven at each current (heating branch)."""
        return np.interp(np.asarray(currents_A, dtype=float), self.grid_A, self.steady_T_C)

    def max_reach_deg(self) -> tuple[float, float]:
        """(smallest, largest) steady tilt reachable within the temperature cap over directions."""
        r = np.concatenate(self.reach_deg)
        return float(r.min()), float(r.max())


def settle(consts: np.ndarray, currents_A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run constant currents (N, 3) from a cold upright neck for ``_SETTLE_S``; (state, out)."""
    n = currents_A.shape[0]
    state = np.empty((n, L.N_STATE))
    out = np.empty((n, L.N_OUT))
    steps = int(round(_SETTLE_S / _SIM_DT_S))
    for s in range(0, n, _CHUNK):
        m = min(n, s + _CHUNK) - s
        x = initial_state(consts, m)
        cur = np.ascontiguousarray(currents_A[s:s + m])
        left = np.full(m, np.inf)
        o = np.empty((m, L.N_OUT))
        for _ in range(steps):
            step_inplace(consts, x, cur, _SIM_DT_S, 1, left, o)
        state[s:s + m], out[s:s + m] = x, o
    return state, out


def fine_index(n: int) -> np.ndarray:
    return np.linspace(0, n - 1, (n - 1) * _UPSAMPLE + 1)


def _interp2(m: np.ndarray, axis: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Separable linear interpolation of m (n, n, 2) onto fine x fine."""
    a = np.stack([np.stack([np.interp(fine, axis, m[:, j, c]) for j in range(m.shape[1])], 1)
                  for c in range(2)], -1)
    return np.stack([np.stack([np.interp(fine, axis, a[i, :, c]) for i in range(a.shape[0])], 0)
                     for c in range(2)], -1)


def _bilinear(table: np.ndarray, xs: np.ndarray, ys: np.ndarray, x: float, y: float):
    x = min(max(x, xs[0]), xs[-1])
    y = min(max(y, ys[0]), ys[-1])
    i = min(int(np.searchsorted(xs, x, side="right")) - 1, xs.size - 2)
    j = min(int(np.searchsorted(ys, y, side="right")) - 1, ys.size - 2)
    tx = (x - xs[i]) / (xs[i + 1] - xs[i])
    ty = (y - ys[j]) / (ys[j + 1] - ys[j])
    v = ((1 - tx) * (1 - ty) * table[i, j] + tx * (1 - ty) * table[i + 1, j]
         + (1 - tx) * ty * table[i, j + 1] + tx * ty * table[i + 1, j + 1])
    return float(v[0]), float(v[1])


_CACHE: dict[tuple[bytes, float], SteadyStateMap] = {}


def steady_state_map(params: NeckParams | None = None, temp_cap_C: float = 150.0) -> SteadyStateMap:
    """The map for these parameters and cap, built once per process (keyed on the packed
    plant constants, so equal parameters share one map whatever their provenance notes)."""
    params = params if params is not None else default_params()
    key = (constants_from_params(params).tobytes(), float(temp_cap_C))
    if key not in _CACHE:
        _CACHE[key] = SteadyStateMap(params, temp_cap_C)
    return _CACHE[key]
