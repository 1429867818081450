"""Bounded, robust least squares for many candidate models at once (lockstep Levenberg-Marquardt).

Every candidate (the nominal refit, nominal + one effect, nominal + a pair) is a set of free
parameters in unit coordinates (each bound mapped to [0, 1], log scale where the parameter
spans decades). One iteration evaluates, for all unfinished candidates together, the
finite-difference Jacobian columns (one batched simulation; sensor-only columns need no
simulation) and then three damped trial steps per candidate (a second batched simulation).

Cost: mean Huber loss of the scaled residuals (``model.residual_vector``) over the fitting
samples + ``PRIOR_WEIGHT`` x sum of squared prior residuals of the nominal parameters. Huber
residuals are handled by iteratively reweighted least squares. Bounds: projected steps, with
parameters held at a bound when the gradient pushes outward.

Why not ``scipy.optimize.least_squares``: it drives one problem at a time through a Python
callback, while here the Jacobian columns and trial steps of *all* candidates (nominal, nine
effects, structural discrepancies, pairs) share one batched simulation per iteration -- the
plant's cost is per simulated rig-step, so lockstep is several times faster for the same fits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from .model import Model, ParamSpec, Prediction, residual_vector

HUBER_C = 3.0  # in scaled residual units (3 deg of theta)
# A 1-sigma move of a baseline parameter costs as much as a 0.022 deg RMS tilt misfit. At 0.005
# (0.07 deg) a rig 2-3 sigma from the defaults -- the independent rig's median EI is x2.5 --
# paid more for its own baseline than a small effect removes, so whichever effect let the
# baseline move back toward the defaults was credited with that (effect-free independent-rig
# datasets: nominal held-out gap 0.52 -> 0.44 deg, the best wrong effect 16 -> 8 %).
PRIOR_WEIGHT = 0.0005
FD_STEP = 0.01  # unit coordinates
LAMBDAS = (0.25, 1.0, 4.0)


def huber(r: np.ndarray, c: float = HUBER_C) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= c, r * r, 2 * c * a - c * c)


@dataclass
class Candidate:
    name: str
    effects: tuple[str, ...]
    specs: list[ParamSpec]
    fixed: dict[str, float] = field(default_factory=dict)
    u: np.ndarray | None = None
    mu: float = 1e-2
    cost: float = math.inf
    r: np.ndarray | None = None  # scaled data residuals at u (fit samples)
    pred: Prediction | None = None
    J: np.ndarray | None = None
    J_prior: np.ndarray | None = None
    fails: int = 0
    small: int = 0  # consecutive accepted steps that improved the cost by less than rtol
    iters: int = 0
    done: bool = False
    # fitted to these model predictions instead of the recordings (what a baseline shift can
    # make of an effect the model itself produces: ``diagnose.absorption``)
    target: Prediction | None = None

    def __post_init__(self):
        if self.u is None:
            self.u = np.array([s.to_unit(s.start) for s in self.specs])

    def u_from(self, values: Mapping[str, float]) -> np.ndarray:
        """Unit coordinates of natural ``values`` (missing ones at their start), clipped into
        the bounds."""
        return np.array([s.to_unit(min(max(values.get(s.key, s.start), s.lower), s.upper))
                         for s in self.specs])

    def setting(self, u: np.ndarray | None = None) -> dict[str, float]:
        u = self.u if u is None else u
        out = dict(self.fixed)
        for s, x in zip(self.specs, u):
            out[s.key] = s.from_unit(float(x))
        return out

    @property
    def values(self) -> dict[str, float]:
        return {s.key: s.from_unit(float(x)) for s, x in zip(self.specs, self.u)}

    def prior_res(self, u: np.ndarray) -> np.ndarray:
        return np.array([s.prior_residual(s.from_unit(float(x))) for s, x in zip(self.specs, u)
                         if s.prior_sigma is not None])


class Fitter:
    """Runs candidates in lockstep on a model and a mask of fitting samples."""

    def __init__(self, model: Model, fit_mask: np.ndarray):
        self.model = model
        self.mask = fit_mask
        self.n = None

    # -- cost ---------------------------------------------------------------------------------
    def data_res(self, pred: Prediction, target: Prediction | None = None) -> np.ndarray:
        r = residual_vector(self.model.data, pred, self.mask, target)
        if self.n is None:
            self.n = r.size
        return r

    def cost_of(self, cand: Candidate, u: np.ndarray, r: np.ndarray) -> float:
        pr = cand.prior_res(u)
        return float(huber(r).sum() / r.size + PRIOR_WEIGHT * (pr ** 2).sum())

    def evaluate(self, cands: Sequence[Candidate]) -> None:
        """Set cost/r/pred of candidates at their current u (one batch)."""
        preds = self.model.predict([c.setting() for c in cands])
        for c, p in zip(cands, preds):
            c.pred = p
            c.r = self.data_res(p, c.target)
            c.cost = self.cost_of(c, c.u, c.r)

    # -- lockstep LM --------------------------------------------------------------------------
    def run(self, cands: Sequence[Candidate], max_iter: int = 12, rtol: float = 2e-3,
            evaluate_first: bool = True) -> None:
        if evaluate_first:
            self.evaluate([c for c in cands if c.r is None or c.pred is None])
        for it in range(max_iter):
            active = [c for c in cands if not c.done and len(c.specs)]
            for c in cands:
                if not len(c.specs):
                    c.done = True
            if not active:
                break
            need_J = [c for c in active if c.J is None]
            if need_J:
                self._jacobians(need_J)
            # trial steps
            trials, owners = [], []
            for c in active:
                for lam in LAMBDAS:
                    u_new = self._step(c, c.mu * lam)
                    trials.append(u_new)
                    owners.append(c)
            preds = self.model.predict([o.setting(u) for o, u in zip(owners, trials)])
            best: dict[int, tuple[float, np.ndarray, np.ndarray, Prediction, float]] = {}
            for k, (o, u, p) in enumerate(zip(owners, trials, preds)):
                r = self.data_res(p, o.target)
                cost = self.cost_of(o, u, r)
                lam = LAMBDAS[k % len(LAMBDAS)]
                if id(o) not in best or cost < best[id(o)][0]:
                    best[id(o)] = (cost, u, r, p, lam)
            for c in active:
                cost, u, r, p, lam = best[id(c)]
                c.iters += 1
                if cost < c.cost - 1e-15:
                    rel = (c.cost - cost) / max(c.cost, 1e-12)
                    c.u, c.r, c.pred, c.cost = u, r, p, cost
                    c.mu = max(c.mu * lam * 0.5, 1e-6)
                    c.J = None
                    c.fails = 0
                    # one small step may be a damped step in a curved valley: stop after two
                    c.small = c.small + 1 if rel < rtol else 0
                    if c.small >= 2:
                        c.done = True
                else:
                    c.mu *= 16.0
                    c.fails += 1
                    if c.fails >= 3:
                        c.done = True
        for c in cands:
            c.done = True

    def _jacobians(self, cands: Sequence[Candidate]) -> None:
        settings, index = [], []
        for c in cands:
            base_k = len(settings)
            settings.append(c.setting())
            cols = []
            for i in range(len(c.specs)):
                u = c.u.copy()
                h = FD_STEP if u[i] + FD_STEP <= 1.0 else -FD_STEP
                u[i] += h
                cols.append((len(settings), h, u))
                settings.append(c.setting(u))
            index.append((base_k, cols))
        preds = self.model.predict(settings)
        for c, (base_k, cols) in zip(cands, index):
            r0 = self.data_res(preds[base_k], c.target)
            c.r, c.pred = r0, preds[base_k]
            c.cost = self.cost_of(c, c.u, r0)
            J = np.empty((r0.size, len(cols)))
            Jp = []
            p0 = c.prior_res(c.u)
            for j, (k, h, u) in enumerate(cols):
                J[:, j] = (self.data_res(preds[k], c.target) - r0) / h
                Jp.append((c.prior_res(u) - p0) / h if p0.size else np.zeros(0))
            c.J = J
            c.J_prior = np.array(Jp).T if p0.size else np.zeros((0, len(cols)))

    def _step(self, c: Candidate, mu: float) -> np.ndarray:
        """Damped Gauss-Newton step with IRLS Huber weights, projected on the unit box."""
        r, J = c.r, c.J
        a = np.abs(r)
        w = np.where(a <= HUBER_C, 1.0, HUBER_C / np.maximum(a, 1e-12))
        n = r.size
        sw = np.sqrt(w / n)
        A = J * sw[:, None]
        b = r * sw
        pr = c.prior_res(c.u)
        if pr.size:
            A = np.vstack([A, math.sqrt(PRIOR_WEIGHT) * c.J_prior])
            b = np.concatenate([b, math.sqrt(PRIOR_WEIGHT) * pr])
        g = A.T @ b
        H = A.T @ A
        free = np.ones(c.u.size, bool)
        free &= ~((c.u <= 1e-9) & (g > 0))  # at lower bound, descent direction is -g
        free &= ~((c.u >= 1 - 1e-9) & (g < 0))
        delta = np.zeros(c.u.size)
        if free.any():
            Hf = H[np.ix_(free, free)]
            D = np.diag(np.diag(Hf) + 1e-9)
            try:
                delta[free] = -np.linalg.solve(Hf + mu * D, g[free])
            except np.linalg.LinAlgError:
                delta[free] = -g[free] / (np.diag(Hf) + mu + 1e-9)
        return np.clip(c.u + delta, 0.0, 1.0)


def covariance(cand: Candidate, r: np.ndarray, J: np.ndarray, J_prior: np.ndarray,
               n_eff: float) -> tuple[np.ndarray, np.ndarray]:
    """(natural-unit std per parameter, correlation matrix) from the Gauss-Newton Hessian.

    The residual variance is inflated by n / n_eff (residuals are autocorrelated in time)."""
    n = r.size
    s2 = float(np.mean(r ** 2)) * n / max(n_eff, 1.0)
    H = J.T @ J / s2 + (J_prior.T @ J_prior if J_prior.size else 0.0)
    try:
        cov_u = np.linalg.pinv(H)
    except np.linalg.LinAlgError:
        cov_u = np.full((J.shape[1], J.shape[1]), np.nan)
    # natural units: dv/du
    dvdu = []
    for s, x in zip(cand.specs, cand.u):
        h = 1e-4
        a, b = s.from_unit(max(x - h, 0)), s.from_unit(min(x + h, 1))
        dvdu.append((b - a) / (min(x + h, 1) - max(x - h, 0)))
    dvdu = np.array(dvdu)
    std_u = np.sqrt(np.clip(np.diag(cov_u), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(std_u, std_u)
    return std_u * np.abs(dvdu), np.nan_to_num(corr)
