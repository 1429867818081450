"""Where the residual lies: by signal, phase (from the commanded currents), muscle and current.

Phases, per sample, from the commanded currents only (what the host knows):

* ``heating``: some muscle is commanded on,
* ``cooling``: all off, within ``COOLING_S`` after the last switch-off in this recording,
* ``rest``: all off, before the first switch-on or more than ``COOLING_S`` after the last one.

Co-activation, per tilt sample: how many muscles are on or were switched off within
``COOLING_S`` (still warm): one, or several. A model whose single muscles fit while the
samples with several warm muscles do not is wrong in how the muscles' pulls and histories
combine (antagonists loading a warm spring, pennate geometry), not in any one muscle.

For theta and phi the muscle is the active one (the highest commanded current while heating,
the last one switched off while cooling; none at rest). Temperature channel k is labelled by
its own muscle and by its own phase (muscle k on / recently off / neither).

Residual energy: theta and weighted phi in deg^2, temperatures as (e_T / SIGMA_T)^2 / 3 (so
the three thermistors together weigh like one tilt signal with 3 C ~ 1 deg) -- the same
scaling as the fit.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .model import SIGMA_T

COOLING_S = 20.0  # about one cooling time constant of the calibrated springs (~22 s)
PHASES = ("heating", "cooling", "rest")


def phases(t: np.ndarray, cmd: np.ndarray, cooling_s: float = COOLING_S):
    """(phase index (n,) 0/1/2, muscle (n,) 0 = none else 1..3, current (n,) A) for tilt."""
    n = t.size
    on = cmd > 0
    any_on = on.any(axis=1)
    phase = np.full(n, 2, int)
    muscle = np.zeros(n, int)
    level = np.zeros(n)
    last_off_t = -math.inf
    last_m, last_i = 0, 0.0
    for j in range(n):
        if any_on[j]:
            phase[j] = 0
            k = int(np.argmax(cmd[j]))
            muscle[j] = k + 1
            level[j] = cmd[j, k]
            last_m, last_i = k + 1, cmd[j, k]
            last_off_t = t[j]
        elif t[j] - last_off_t <= cooling_s:
            phase[j] = 1
            muscle[j] = last_m
            level[j] = last_i
    return phase, muscle, level


def channel_phases(t: np.ndarray, cmd_k: np.ndarray, cooling_s: float = COOLING_S) -> np.ndarray:
    """Phase of one muscle's own channel (its temperature)."""
    on = cmd_k > 0
    last_on = np.maximum.accumulate(np.where(on, t, -np.inf))  # -inf before the first
    return np.where(on, 0, np.where(t - last_on <= cooling_s, 1, 2))


ACTIVATION = ("one", "several")  # muscles on or still warm at a tilt sample (none: rest)
# Several warm muscles only stand out by this much more tilt error (RMS) as well: the project's
# own rig, effect-free, leaves 0.04 deg with one muscle warm and 0.08 deg with several (a
# noise-level difference), an independently written one 0.20-0.87 deg against 0.51-1.41 deg.
ACTIVATION_MIN_DEG = 0.1


def warm_muscles(t: np.ndarray, cmd: np.ndarray, cooling_s: float = COOLING_S) -> np.ndarray:
    """Per sample, how many muscles are on or were switched off within ``cooling_s``."""
    return _warm_count([channel_phases(t, cmd[:, k], cooling_s) for k in range(cmd.shape[1])])


def _warm_count(channel_phase: Sequence[np.ndarray]) -> np.ndarray:
    return sum((p < 2).astype(int) for p in channel_phase)


def decompose(recs: Sequence[dict]) -> dict:
    """Residual energy shares.

    ``recs``: per recording dicts with ``t``, ``cmd`` (n, 3), ``e_theta``, ``e_phi`` (n,) and
    optionally ``e_T`` (n, 3). Returns {"items": [...], "by_current": [...], "by_signal": {...},
    "by_phase": {...}, "total_energy": float, "n_samples": int}."""
    acc: dict[tuple, list[float]] = {}
    cur_acc: dict[tuple, float] = {}
    n_total = 0
    n_read_T = 0  # temperature samples with a reading
    time_count: dict[tuple, int] = {}
    act_acc = {a: [0.0, 0] for a in ACTIVATION}  # tilt energy (theta + phi), samples
    for r in recs:
        t, cmd = r["t"], r["cmd"]
        ph, mu, lvl = phases(t, cmd)
        n_total += t.size
        ch = [channel_phases(t, cmd[:, k]) for k in range(3)]  # temperatures and co-activation
        warm = _warm_count(ch)
        tilt_e2 = r["e_theta"] ** 2 + r["e_phi"] ** 2
        for a, sel in zip(ACTIVATION, (warm == 1, warm >= 2)):
            act_acc[a][0] += float(tilt_e2[sel].sum())
            act_acc[a][1] += int(sel.sum())
        signals = [("theta", r["e_theta"] ** 2, ph, mu), ("phi", r["e_phi"] ** 2, ph, mu)]
        if r.get("e_T") is not None:
            for k in range(3):
                e = (r["e_T"][:, k] / SIGMA_T) ** 2 / 3.0
                read = np.isfinite(e)  # a channel not recorded, or a missing reading
                n_read_T += int(read.sum())
                signals.append(("temperature", np.where(read, e, 0.0),
                                np.where(read, ch[k], -1), np.full(t.size, k + 1)))
        for sig, e2, p, m in signals:
            for pi in range(3):
                for mk in range(4):
                    sel = (p == pi) & (m == mk)
                    if not sel.any():
                        continue
                    key = (sig, PHASES[pi], mk)
                    a = acc.setdefault(key, [0.0, 0])
                    a[0] += float(e2[sel].sum())
                    a[1] += int(sel.sum())
            bins = np.round(lvl * 2) / 2
            for b in np.unique(bins):
                sel = bins == b
                cur_acc[(sig, float(b))] = cur_acc.get((sig, float(b)), 0.0) + float(e2[sel].sum())
        for pi in range(3):
            for mk in range(4):
                sel = (ph == pi) & (mu == mk)
                time_count[(PHASES[pi], mk)] = time_count.get((PHASES[pi], mk), 0) + int(sel.sum())
    total = sum(v[0] for v in acc.values()) or 1e-300
    items = []
    for (sig, phase, mk), (energy, count) in acc.items():
        items.append({"signal": sig, "phase": phase, "muscle": (mk if mk else None),
                      "share": energy / total,
                      # fraction of this signal's samples that fall in the group
                      "time_fraction": count / max(1, n_read_T if sig == "temperature" else n_total),
                      "rms": math.sqrt(energy / max(count, 1)) * (SIGMA_T * math.sqrt(3) if sig == "temperature" else 1.0)})
    items.sort(key=lambda d: -d["share"])
    by_signal: dict[str, float] = {}
    by_phase: dict[str, float] = {}
    for it in items:
        by_signal[it["signal"]] = by_signal.get(it["signal"], 0.0) + it["share"]
        by_phase[it["phase"]] = by_phase.get(it["phase"], 0.0) + it["share"]
    by_current = [{"signal": s, "current_A": b, "share": e / total}
                  for (s, b), e in sorted(cur_acc.items(), key=lambda kv: (kv[0][0], kv[0][1]))]
    phase_time = {p: sum(c for (pp, _), c in time_count.items() if pp == p) / max(n_total, 1)
                  for p in PHASES}
    # RMS tilt error (theta and phi pooled, deg) where one / several muscles are warm
    by_activation = {a: {"rms": math.sqrt(e / (2 * c)) if c else None,
                         "time_fraction": c / max(n_total, 1)}
                     for a, (e, c) in act_acc.items()}
    return {"items": items, "by_current": by_current, "by_signal": by_signal,
            "by_phase": by_phase, "phase_time_fraction": phase_time,
            "by_activation": by_activation, "total_energy": total, "n_samples": n_total}


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    if a.size < 3:
        return 0.0
    ra = np.argsort(np.argsort(a)).astype(float)
    rb = np.argsort(np.argsort(b)).astype(float)
    ra -= ra.mean()
    rb -= rb.mean()
    den = math.sqrt(float((ra * ra).sum() * (rb * rb).sum()))
    return float((ra * rb).sum() / den) if den > 0 else 0.0


def _densest(density: dict, alike: str):
    """The key whose residual density is over 1.5x every other's, ``alike`` when none stands
    out, None when there is nothing to compare."""
    if not density:
        return None
    top = max(density, key=density.get)
    others = [v for k, v in density.items() if k != top]
    return top if others and density[top] > 1.5 * max(others) else alike


def pattern(dec: dict, recs: Sequence[dict]) -> dict:
    """A short reading of a decomposition: which signal, whether one phase or muscle
    concentrates the residual (share per unit of time), and whether it grows across the
    recordings (file order)."""
    by_sig = dec["by_signal"]
    tilt = by_sig.get("theta", 0.0) + by_sig.get("phi", 0.0)
    sig = max(by_sig, key=by_sig.get) if by_sig else None
    # density of tilt residual energy per phase: share / time fraction
    tilt_items = [it for it in dec["items"] if it["signal"] in ("theta", "phi")]
    tot_tilt = sum(it["share"] for it in tilt_items) or 1e-300
    dens = {}
    for ph in PHASES:
        share = sum(it["share"] for it in tilt_items if it["phase"] == ph) / tot_tilt
        tf = dec["phase_time_fraction"].get(ph, 0.0)
        if tf > 0.02:
            dens[ph] = share / tf
    concentrated = _densest(dens, "all phases alike")
    mus = {}
    for m in (1, 2, 3):
        e = sum(it["share"] for it in tilt_items if it["muscle"] == m)
        tf = sum(it["time_fraction"] for it in tilt_items if it["muscle"] == m and it["signal"] == "theta")
        if tf > 0.02:
            mus[m] = e / tot_tilt / tf
    muscle = _densest(mus, "all muscles alike")
    # tilt residual density (mean square) with one and with several muscles warm
    act = dec["by_activation"]
    rms = {a: v["rms"] for a, v in act.items()
           if v["rms"] is not None and v["time_fraction"] > 0.02}
    activation = (_densest({a: x * x for a, x in rms.items()}, "one and several alike")
                  if len(rms) == 2 else None)
    if activation in ACTIVATION and abs(rms["several"] - rms["one"]) < ACTIVATION_MIN_DEG:
        activation = "one and several alike"
    per = np.array([math.sqrt(float(np.mean(r["e_theta"] ** 2 + r["e_phi"] ** 2) / 2)) for r in recs])
    trend = _spearman(np.arange(per.size, dtype=float), per)
    return {"dominant_signal": sig, "tilt_share": tilt, "temperature_share": by_sig.get("temperature", 0.0),
            "phase_density": dens, "concentrated_in_phase": concentrated,
            "muscle_density": {str(k): v for k, v in mus.items()}, "concentrated_in_muscle": muscle,
            "activation_rms_deg": {a: v["rms"] for a, v in act.items()},
            "concentrated_in_activation": activation,
            "per_recording_rms": per.tolist(), "trend_across_recordings": trend}
