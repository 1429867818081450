"""The diagnosis' outputs: REPORT.json (the contract of design.md 2.3 plus detail), a readable
text report, plots, and the corrected model (parameter JSON + effects JSON)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .. import effects as fx
from . import currents, repeats
from . import diagnose as D
from .model import ALL_STRUCTURE, HEAT_CAPACITY_PRIOR_SIGMA, clip_to_catalogue

REPORT_VERSION = 1


def _clean(x: Any) -> Any:
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        f = float(x)
        return f if math.isfinite(f) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _r(x: float, n: int = 4) -> float | None:
    """Rounded for the report; None (JSON null) where a statistic is undefined (NaN)."""
    x = float(x)
    return None if math.isnan(x) else float(round(x, n))


def _warming(s: "D.Comparison") -> dict:
    """The cold neighbours' held-out temperatures (``D.warming_compare``), when compared."""
    w = s.warming
    if w is None:
        return {}
    return {"heldout_cold_neighbours_T": {**_thermistors(w), "n_eff": _r(w.n_eff, 1),
                                          "samples": w.samples, "warms": bool(D.warms(s))}}


def _switched_off(s: D.Comparison) -> dict:
    """Its fit on the fitting recordings, and that fit with the effect (a pair's weaker member)
    switched off there and on the held-out recordings (``D.acts``)."""
    def gap(o: "D.Comparison | None", which: str) -> float | None:
        return None if o is None else _r(getattr(o, which))
    return {"fitting_gap": gap(s.vs_off, "gap_after_deg"),
            "fitting_gap_switched_off": gap(s.vs_off, "gap_before_deg"),
            "heldout_gap_switched_off": gap(s.vs_off_heldout, "gap_before_deg")}


def _on_structure(s: D.Comparison) -> dict:
    o = s.on_structure
    if o is None:
        return {}
    return {"on_structure": {"heldout_gap_structure": _r(o.gap_before_deg),
                             "heldout_gap_after": _r(o.gap_after_deg),
                             "heldout_reduction": _r(o.reduction),
                             "heldout_recording_reduction_median": _r(o.rec_reduction_median),
                             "significant": bool(D.significant(o))}}


def _built_up(s: D.Comparison, names: list[str]) -> dict:
    """An effect that builds up over use, judged also on the held-out recordings where it has
    (``D.judgements``): which, and its comparisons there."""
    b = s.built_up
    if b is None:
        return {}
    vs = b.vs_structure
    return {"heldout_built_up": {"recordings": [names[r] for r in b.judged_recordings],
                                 "heldout_gap_before": _r(b.gap_before_deg),
                                 "heldout_gap_after": _r(b.gap_after_deg),
                                 "heldout_reduction": _r(b.reduction),
                                 "heldout_t": _r(b.t, 2),
                                 "heldout_F": _r(b.F, 3), "heldout_F_crit": _r(b.F_crit, 3),
                                 "heldout_recordings_improved": f"{b.recordings_improved}/{b.recordings}",
                                 "heldout_recording_reduction_median": _r(b.rec_reduction_median),
                                 "significant_vs_nominal": bool(D.significant(b)),
                                 "heldout_gap_structure": (_r(vs.gap_before_deg)
                                                           if vs is not None else None),
                                 **_on_structure(b)}}


def _thermistors(w: "D.Warming") -> dict:
    """The figures every thermistor comparison reports."""
    return {"rms_before_C": _r(w.rms_before_C), "rms_after_C": _r(w.rms_after_C),
            "reduction": _r(w.reduction), "F": _r(w.F, 3), "F_crit": _r(w.F_crit, 3)}


def _temperatures(s: "D.Comparison") -> dict:
    """Every held-out thermistor reading (``D.temperature_evidence``): a thermal effect's
    evidence beyond the tilt (``D.heats``), when compared."""
    w, v = s.temperatures, s.temperatures_vs_structure
    if w is None:
        return {}
    return {"heldout_T": {
        **_thermistors(w), "reduction_vs_structure": None if v is None else _r(v.reduction),
        "F_vs_structure": None if v is None else _r(v.F, 3), "fits": bool(D.heats(s))}}


def _activation_line(L: list[str], pattern: dict, prefix: str, remaining: bool = False) -> None:
    """The tilt residual with one muscle warm against several (``localize.warm_muscles``);
    ``remaining``: of the verdict model, which says what that concentration means."""
    rms = pattern.get("activation_rms_deg") or {}
    if rms.get("one") is None or rms.get("several") is None:
        return
    L.append(f"{prefix}co-activation: {pattern['concentrated_in_activation']} (tilt RMS with one "
             f"muscle warm {rms['one']:.2f} deg, several {rms['several']:.2f} deg)")
    if remaining and pattern["concentrated_in_activation"] == "several":
        L.append("      the muscles fit one at a time but not together, and no effect of the verdict "
                 "takes it:")
        L.append("      how their pulls and histories combine (antagonists stretching a warm spring,")
        L.append("      the pennate geometry) likely differs from the model's, unless an effect of their")
        L.append("      interplay (friction under changing moments, neighbour heating) is missed or mis-sized")


def _warming_line(L: list[str], entry: dict) -> None:
    """The held-out temperatures under an effect's or a pair's line, when compared: all of them
    (a thermal effect) and the cold neighbours'."""
    t = entry.get("heldout_T")
    if t:
        vs = ("" if t["reduction_vs_structure"] is None
              else f"; {100 * t['reduction_vs_structure']:+.0f} % vs the structure")
        L.append(f"    {'':25s} springs' temperatures {t['rms_before_C']:.2f} -> "
                 f"{t['rms_after_C']:.2f} C ({100 * t['reduction']:+.0f} %, F {t['F']:.2f} "
                 f"vs {t['F_crit']:.2f}{vs}){': the effect explains them' if t['fits'] else ''}")
    w = entry.get("heldout_cold_neighbours_T")
    if w:
        L.append(f"    {'':25s} unpowered springs' temperature {w['rms_before_C']:.2f} -> "
                 f"{w['rms_after_C']:.2f} C ({100 * w['reduction']:+.0f} %, F {w['F']:.2f} "
                 f"vs {w['F_crit']:.2f}){': they warm as the effect predicts' if w['warms'] else ''}")


def _unidentified_note(key: str, v: dict, calibration: dict) -> str:
    """What a baseline parameter's line says when the data do not pin it."""
    if v.get("identified", True):
        return ""
    if key == "h_scale" and calibration.get("cooling_time_constant_s", {}).get("identified"):
        return "  not identified alone: only as m c/(h A) (below)"
    return "  not identified by these data (held by its prior)"


def build_report(dg: "D.Diagnosis", dataset_path: str | Path | None = None) -> dict:
    data = dg.data
    nom_cmp = D.gap_stats(data, dg.nominal.pred, D.sample_masks(data, dg.hold_rec)[1])
    effects = []
    for c in dg.singles:
        s = dg.single_cmp[c.name]
        _, hold = D.sample_masks(data, dg.hold_rec)
        g = D.gap_stats(data, c.pred, hold)
        named_on = D.grounds(s)
        effects.append({
            "name": c.name,
            "params": {k: _r(v, 6) for k, v in dg.model.effects_of(c.setting(), [c.name])[c.name].items()},
            "heldout_gap_before": _r(s.gap_before_deg),
            "heldout_gap_after": _r(s.gap_after_deg),
            "heldout_reduction": _r(s.reduction),
            "heldout_t": _r(s.t, 2),
            "heldout_F": _r(s.F, 3), "heldout_F_crit": _r(s.F_crit, 3),
            "heldout_n_eff": _r(s.n_eff, 1),
            "heldout_blocks_improved": f"{s.blocks_improved}/{s.blocks}",
            "heldout_recordings_improved": f"{s.recordings_improved}/{s.recordings}",
            # the held-out recordings as units (``diagnose.by_recordings``)
            "heldout_recording_reduction_median": _r(s.rec_reduction_median),
            "heldout_recording_t": _r(s.rec_t, 2),
            "heldout_recording_abs_reduction_median": _r(s.rec_abs_reduction_median_deg),
            # responsible (``diagnose.responsible``: any grounds), and the evidence it is named
            # on (``diagnose.grounds``); empty when it is not
            "significant": bool(named_on),
            "grounds": list(named_on),
            "significant_vs_nominal": bool(D.significant_any(s)),
            # why its fit is no evidence whatever the tests say (``Comparison.unresolved``)
            "unresolved": s.unresolved,
            "heldout_gap_structure": (_r(s.vs_structure.gap_before_deg)
                                      if s.vs_structure is not None else None),
            # fitted on top of that structural discrepancy, where the plain comparison failed
            # (``diagnose.beats_structure``, nested)
            **_on_structure(s),
            **_switched_off(s),
            "heldout_theta_rmse_after": _r(g["theta_rmse"]),
            "heldout_phi_rmse_after": _r(g["phi_rmse"]),
            "signature": fx.EFFECTS[c.name].signature,
            **_built_up(s, data.names),
            **_warming(s),
            **_temperatures(s),
            # a named growth that still air, fitted as a check, matches (``still_air_caveat``)
            **({"still_air": {"h_exponent": _r(dg.still_air["h_exponent"], 3),
                              "heldout_gap_still_air": _r(dg.still_air["heldout_gap_with"]),
                              "note": dg.still_air["note"]}}
               if dg.still_air is not None and c.name == dg.still_air["effect"] else {}),
        })
    pairs = []
    for p in dg.pairs:
        s = dg.pair_cmp[p.name]
        pairs.append({
            "name": p.name, "effects": list(p.effects),
            "params": {n: {k: _r(v, 6) for k, v in vals.items()}
                       for n, vals in dg.model.effects_of(p.setting(), p.effects).items()},
            "heldout_gap_before": _r(s.vs_nominal.gap_before_deg),
            "heldout_gap_after": _r(s.gap_after_deg),
            "heldout_gap_best_single": _r(s.gap_before_deg),
            "heldout_reduction_vs_best_single": _r(s.reduction),
            "heldout_t_vs_best_single": _r(s.t, 2),
            # the generic structural rival on the pair's reference: the best discrepancy on
            # top of the first effect (after a responsible single), else on the baseline
            "heldout_gap_structure": (_r(s.vs_structure.gap_before_deg)
                                      if s.vs_structure is not None else None),
            **_switched_off(s),
            "significant": bool(s.accepted),
            "unresolved": s.unresolved,
            **_warming(s),
            **_temperatures(s),
        })
    loc = [{"signal": it["signal"], "phase": it["phase"], "muscle": it["muscle"],
            "share": _r(it["share"]), "time_fraction": _r(it["time_fraction"]),
            "rms": _r(it["rms"])} for it in dg.localization["items"]]
    loc_rem = [{"signal": it["signal"], "phase": it["phase"], "muscle": it["muscle"],
                "share": _r(it["share"]), "time_fraction": _r(it["time_fraction"]),
                "rms": _r(it["rms"])} for it in dg.localization_remaining["items"]]
    corrected_effects = dg.model.effects_of(dg.final.setting(), dg.verdict)
    fc = dg.final_cmp
    rem = dg.remaining
    report = {
        "tool": "neck_env.gap", "report_version": REPORT_VERSION,
        "dataset": str(dataset_path) if dataset_path is not None else None,
        "recordings": data.names,
        "heldout_recordings": [n for n, h in zip(data.names, dg.hold_rec) if h],
        "split": dg.split_note,
        "verdict": list(dg.verdict),
        "unexplained": bool(dg.unexplained),
        "ambiguous": [{"effect": a["effect"], "with": list(a["with"]), "note": a["note"],
                       "heldout_gap_nominal": _r(a["heldout_gap_nominal"]),
                       "heldout_gap_effect": _r(a["heldout_gap_effect"]),
                       "effect_size_deg": _r(a["effect_size_deg"], 3),
                       # the rival's own held-out gap where it is not a baseline shift
                       **({"heldout_gap_with": _r(a["heldout_gap_with"])}
                          if "heldout_gap_with" in a else {})} for a in dg.ambiguous],
        "unexplained_reasons": list(dg.reasons),
        "measured_currents": (dg.measured_currents.to_dict()
                              if dg.measured_currents is not None else None),
        "verdict_by_currents": dict(dg.by_currents),
        "repeats": dg.repeated.to_dict() if dg.repeated is not None else None,
        "verdict_by_repeats": dict(dg.by_repeats),
        "absorption": [{"effect": a["effect"], "reference": {k: _r(v, 6) for k, v in a["reference"].items()},
                        "heldout_size_deg": _r(a["size_deg"]), "heldout_left_deg": _r(a["left_deg"]),
                        "absorbed": _r(a["absorbed"], 3), "by": list(a["by"]),
                        "seen_in_temperatures": bool(a["seen_in_temperatures"]),
                        "separate": a["separate"]}
                       for a in dg.absorption],
        "effects": effects,
        "pairs": pairs,
        "structure": [{"name": c.name.split(":", 1)[1],
                       "params": {sp.key: _r(c.values[sp.key], 6) for sp in ALL_STRUCTURE[c.name]},
                       "heldout_gap_before": _r(dg.null_cmp[c.name].gap_before_deg),
                       "heldout_gap_after": _r(dg.null_cmp[c.name].gap_after_deg),
                       "heldout_reduction": _r(dg.null_cmp[c.name].reduction)} for c in dg.nulls],
        "localization": loc,
        "localization_summary": {
            "by_signal": {k: _r(v) for k, v in dg.localization["by_signal"].items()},
            "by_phase": {k: _r(v) for k, v in dg.localization["by_phase"].items()},
            "phase_time_fraction": {k: _r(v) for k, v in dg.localization["phase_time_fraction"].items()},
        },
        "localization_pattern": dg.localization["pattern"],
        "localization_remaining_pattern": dg.localization_remaining["pattern"],
        "localization_by_current": [{"signal": d["signal"], "current_A": d["current_A"],
                                     "share": _r(d["share"])} for d in dg.localization["by_current"]],
        "localization_remaining": loc_rem,
        "nominal": {"heldout_gap": _r(nom_cmp["gap"]), "heldout_theta_rmse": _r(nom_cmp["theta_rmse"]),
                    "heldout_phi_rmse": _r(nom_cmp["phi_rmse"]),
                    "params": {k: _r(v, 6) for k, v in dg.nominal.values.items()}},
        "corrected": {"effects": {n: {k: _r(v, 6) for k, v in vals.items()}
                                  for n, vals in corrected_effects.items()},
                      "heldout_gap": _r(fc.gap_after_deg),
                      "heldout_reduction": _r(fc.reduction),
                      "systematic_heldout_residual_deg": _r(rem.systematic_rms_deg),
                      "systematic_tolerance_deg": _r(rem.systematic_tol_deg),
                      "rest_offset_spread_deg": _r(rem.rest_spread_deg),
                      "rest_offset_drift_deg": _r(rem.rest_drift_deg),
                      "rest_offset_drift_r2": _r(rem.rest_drift_r2),
                      "params": {k: _r(v, 6) for k, v in dg.final.values.items()}},
        "calibration": dict(dg.calibration, h_default_W_m2K=dg.model.base.thermal.convection_W_m2K),
        # what REPORT_params.json / REPORT_effects.json carry beyond the verdict model
        "export": _export_entry(dg),
        "ambient": {"value_C": data.ambient, "source": data.ambient_source},
        "temperatures_used": bool(data.has_T),
        # below the threshold the springs never actuated: only effects the thermistors see
        # (``effects.Effect.thermal``) may be named, on the temperatures' evidence
        "actuation": {"moved_deg": _r(dg.moved_deg), "threshold_deg": D.NO_ACTUATION_DEG,
                      "actuated": bool(dg.moved_deg >= D.NO_ACTUATION_DEG),
                      "nameable": list(D.nameable(data, dg.moved_deg))},
        "temperature_readings": {k: _r(v, 4) for k, v in data.T_read_share.items()},
        # recordings that start where the backbone held the neck off its rest reading (the tilt
        # vector as read there, deg): simulated from there (``rest.stuck_starts``)
        "stuck_starts": {data.names[r]: [_r(v, 3) for v in data.stuck_start_tilt_deg[r]]
                         for r in np.flatnonzero(data.stuck)},
        "method": {
            "gap": "RMSE over held-out samples of theta (deg) and phi weighted by "
                   "min(theta_meas, theta_model) / 5 deg (deg), pooled: sqrt((rmse_theta^2 + "
                   "rmse_phi^2) / 2)",
            "significance": f"held-out F test of mean squared tilt error, effective sample size "
                            f"from the residual autocorrelation, level {D.ALPHA}; and reduction "
                            f">= {D.MIN_REL:.0%} and >= {D.MIN_ABS_DEG} deg; and paired t over "
                            f"{D.BLOCK_S:g} s blocks > {D.T_CRIT}, or every held-out block improved "
                            f"(at least {D.MIN_BLOCKS_CONSISTENT}) with the F test, or every "
                            f"held-out recording improved (at least {D.MIN_REC_CONSISTENT}); "
                            f"and beyond the best generic structural discrepancy. Or, for "
                            f"{', '.join(D.WARMING_EFFECTS)} with thermistors: the held-out "
                            f"temperature residual of the springs not yet powered in their "
                            f"recording while a neighbour has been (only heat from a neighbour "
                            f"warms them), each thermistor read from its mean before the "
                            f"first pulse of its recording (an offset is not a warming), falls "
                            f"by the F test at level {D.ALPHA}, by >= "
                            f"{D.WARMING_MIN_REL:.0%} and >= {D.WARMING_MIN_ABS_C} C, with the "
                            f"held-out tilt gap not significantly worse (the F test turned round)",
            "unexplained": f"systematic (3 s smoothed) held-out residual of the final model > "
                           f"max({D.UNEXPLAINED_ABS_DEG} deg, {D.UNEXPLAINED_REL:.0%} of the RMS "
                           f"measured tilt), or the tilt read at rest moving through the dataset "
                           f"(by > {D.UNEXPLAINED_REST_DEG} deg RMS between recordings, or by > "
                           f"{D.UNEXPLAINED_REST_DEG} deg from first to last along a straight "
                           f"line with R^2 > {D.DRIFT_R2}; such a steady drift is "
                           f"fitted as a nuisance by every candidate so that no effect is blamed "
                           f"for its mean; no catalogued effect moves the rest reading)",
            "phases": "heating: a muscle commanded on; cooling: all off within 20 s of the last "
                      "switch-off; rest: otherwise",
        },
        "timing_s": {k: _r(v, 2) for k, v in dg.timing.items()},
        "simulated_rig_steps": int(dg.model.sim_count),
    }
    return _clean(report)


def export_sensors(dg: "D.Diagnosis") -> dict[str, float]:
    """The sensor side of the fit the corrected-model files come from, which NeckParams does
    not hold: the IMU zero offset (deg) to add to the env's tilt and the thermistors' lag (s)
    to read its spring temperatures through. ``calibration.params`` holds the nominal refit's,
    which without the verdict's effects absorbs some of them (independent 12621: a 0.85 s
    delay left out put the nominal lag at 2.0 s against the verdict fit's 0.97 s; replayed
    with the nominal's, the delay's export missed the thermistors by 4.6 C instead of 0.8 C)."""
    return sensors_of((dg.exported or dg.final).setting())


def sensors_of(setting: Mapping[str, float]) -> dict[str, float]:
    """A fit's IMU zero offset (deg) and thermistor lag (s; 0 where none was fitted)."""
    return {k: _r(setting.get(k, 0.0), 6)
            for k in ("offset_x_deg", "offset_y_deg", "thermistor_lag_s")}


def _export_entry(dg: "D.Diagnosis") -> dict:
    """The report's ``export``: the structural discrepancy and the terminals' heat path the
    corrected-model files carry on top of the verdict (``diagnose._export``); each None when
    the held-out data did not show it."""
    x = dg.export
    if x is None:
        return {"structure": None, "params": {}, "evidence": None, "terminals": None,
                "exported": False, "sensors": export_sensors(dg),
                "note": "no generic structural discrepancy improved the held-out tilt or "
                        "temperatures significantly and the held-out temperatures did not need "
                        "the terminals' heat path: the files carry the baseline and the "
                        "verdict's effects"}
    what = " and ".join(w for w, on in (
        ("the terminals' heat path the held-out temperatures needed", x["terminals"] is not None),
        ("a structure no catalogued effect names", x["structure"] is not None)) if on)
    return {**{k: (_r(v, 6) if isinstance(v, float) else v) for k, v in x.items()
               if k not in ("params", "terminals")},
            "params": {k: _r(v, 6) for k, v in x["params"].items()},
            "terminals": (None if x["terminals"] is None
                          else {k: _r(v, 6) for k, v in x["terminals"].items()}),
            "sensors": export_sensors(dg),
            "note": (f"{what}, fitted with the verdict on every recording, so that NeckTrack-v0 "
                     f"built from the files moves and cools as this rig does; not an effect and "
                     f"not in the verdict"
                     if x["exported"] else
                     "a structure significant held out, but refitted with the verdict on every "
                     "recording it fits them no better: the files carry the baseline and the "
                     "verdict's effects")}


def text_report(rep: dict) -> str:
    L = []
    L.append(f"Sim-to-real gap diagnosis of {rep['dataset']}")
    L.append(f"  {len(rep['recordings'])} recordings; held out: {', '.join(rep['heldout_recordings']) or 'last 40 %'}"
             f"; ambient {rep['ambient']['value_C']:.1f} C ({rep['ambient']['source']}); "
             f"temperatures {'used' if rep['temperatures_used'] else 'not recorded'}")
    stuck = rep.get("stuck_starts") or {}
    if stuck:
        L.append(f"  {len(stuck)} recording(s) start at rest off the rest reading, cold and not "
                 f"moving ({', '.join(stuck)}): the backbone held the neck where the one before "
                 f"left it (stiction); simulated from there")
    n = rep["nominal"]
    L.append("")
    L.append(f"Nominal model refitted: held-out gap {n['heldout_gap']:.3f} deg "
             f"(theta RMSE {n['heldout_theta_rmse']:.3f}, weighted phi RMSE {n['heldout_phi_rmse']:.3f})")
    cal = rep["calibration"]["params"]
    heldout_fit = n["params"]
    L.append("    This rig's baseline: fitted on the fitting recordings (the fit whose held-out gap "
             "is above) | on all recordings +- std | vs the defaults")
    for k, v in cal.items():
        vs = (f"x{v['value']:.3g}" if k.endswith("_scale") else
              f"{v['value'] - v['default']:+.3g} C" if k.endswith("shift_C") else "")
        if "prior_center" in v:  # centred on the wire meta.json gives (model.nominal_specs)
            vs += f" (x{v['prior_center']:.3g} for your wire)"
        L.append(f"    {k:20s} {heldout_fit.get(k, float('nan')):10.4g} | {v['value']:10.4g} +- {v['std']:<8.2g}"
                 f" {vs:10s}{'  at bound' if v['at_bound'] else ''}"
                 f"{_unidentified_note(k, v, rep['calibration'])}")
    not_identified = "NOT identified: record longer cooling tails (the rig protocol)"
    tau = rep["calibration"].get("cooling_time_constant_s")
    if tau:
        # the +- is the fit's noise: a rig's thermal structure can bias tau beyond it (gap.md)
        L.append(f"    cooling time constant m c/(h A) = {tau['value']:.3g} +- {tau['std']:.2g} s "
                 f"(noise only; default {tau['default']:.3g} s): "
                 + ("identified by the cooling tails (the thermal figure to compare with another "
                    "model or a bench measurement)" if tau["identified"] else not_identified))
        cold = rep["calibration"].get("cooling_time_constant_cold_terminals_s")
        if cold and cold["identified"] and cold["value"] < 0.95 * tau["value"]:
            L.append(f"    heat drained into the terminals: a tail starts at m c/(h A + G) = "
                     f"{cold['value']:.3g} s while they are cold, and slows as they warm")
    h = rep["calibration"].get("convection_W_m2K")
    if h:
        wire = (f"d {1e3 * h['wire_diameter_m']:.3g} mm, c {h['specific_heat_J_kgK']:.0f} J/kgK, "
                f"{h['heat_capacity_per_area_J_m2K']:.0f} J/m^2K per unit surface")
        if h["identified"]:
            why = (f"identified: the cooling tails' time constant on your wire ({wire}, "
                   f"meta.json); the +- carries a datasheet specific heat's "
                   f"{100 * HEAT_CAPACITY_PRIOR_SIGMA:.0f} % (measure the wire's for a tighter h)")
        elif not h["tau_identified"]:
            why = not_identified
        else:
            why = (f"NOT identified: the recordings pin the time constant, not h (h trades with the "
                   f"heat capacity); this is h on {'the model' if len(h['missing']) == 2 else 'a partly assumed'}"
                   f" wire ({wire}); give {' and '.join(h['missing'])} in meta.json for yours")
        L.append(f"    convection h = {h['value']:.3g} +- {h['std']:.2g} W/m^2K "
                 f"(default {rep['calibration']['h_default_W_m2K']:.3g}): {why}")
    terms = rep["calibration"].get("terminals")
    if terms and terms["selected"]:
        was = terms["without_terminals"]
        p = terms["params"]
        L.append(f"    these thermal figures are from the baseline refitted with heat drained into the "
                 f"terminals (share {p['terminal_share']['value']:.2f}, {p['terminal_tau_s']['value']:.0f} s): "
                 f"it fits the held-out temperatures better ({terms['heldout_T_rms_before_C']:.2f} -> "
                 f"{terms['heldout_T_rms_after_C']:.2f} C, F {terms['heldout_T_F']:.2f}); without "
                 f"it h = {was['convection_W_m2K']['value']:.3g} W/m^2K, time constant "
                 f"{was['cooling_time_constant_s']['value']:.3g} s. Effects are judged on the plain "
                 f"baseline (neck-gap --fit-terminals judges them on this one)")
    weak = rep["calibration"]["weak_directions"]
    if weak:
        L.append("    weakly identifiable: " + "; ".join(
            " ".join(f"{c:+.2f} {k}" for k, c in w["direction"].items()) for w in weak))
    L.append("")
    L.append("Where the gap lies (share of the nominal residual energy):")
    ls = rep["localization_summary"]
    L.append("    by signal: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in ls["by_signal"].items()))
    L.append("    by phase:  " + ", ".join(f"{k} {100 * v:.0f} % (of time {100 * ls['phase_time_fraction'].get(k, 0):.0f} %)"
                                          for k, v in ls["by_phase"].items()))
    pt = rep["localization_pattern"]
    L.append(f"    pattern: {pt['dominant_signal']}; phase: {pt['concentrated_in_phase']}; muscle: "
             f"{pt['concentrated_in_muscle']}; trend across recordings {pt['trend_across_recordings']:+.2f}")
    _activation_line(L, pt, "    ")
    for it in rep["localization"][:6]:
        m = f"muscle {it['muscle']}" if it["muscle"] else "no muscle"
        L.append(f"    {100 * it['share']:5.1f} %  {it['signal']:11s} {it['phase']:8s} {m:10s} "
                 f"(RMS {it['rms']:.2f}, {100 * it['time_fraction']:.0f} % of the time)")
    L.append("")
    L.append("Effects ranked: the verdict's first, then by held-out gap (nominal + effect refitted "
             "on the fitting recordings):")
    for e in rep["effects"]:
        ps = ", ".join(f"{k}={v:.3g}" for k, v in e["params"].items())
        L.append(f"  {'*' if e['significant'] else ' '} {e['name']:25s} {e['heldout_gap_before']:.3f} -> "
                 f"{e['heldout_gap_after']:.3f} deg ({100 * e['heldout_reduction']:+5.1f} %, t {e['heldout_t']:.1f})  {ps}")
        if e.get("grounds"):
            L.append(f"    {'':25s} named on: {', '.join(e['grounds'])}")
        if e.get("unresolved") and e.get("significant_vs_nominal"):
            L.append(f"    {'':25s} not named: {e['unresolved']}")
        b = e.get("heldout_built_up")
        if b:
            L.append(f"    {'':25s} where it has built up ({', '.join(b['recordings'])}): "
                     f"{b['heldout_gap_before']:.3f} -> {b['heldout_gap_after']:.3f} deg "
                     f"({100 * b['heldout_reduction']:+.1f} %, t {b['heldout_t']:.1f})")
        _warming_line(L, e)
    for p in rep["pairs"]:
        rival = (f"; structural rival {p['heldout_gap_structure']:.3f} deg"
                 if p.get("heldout_gap_structure") is not None else "")
        L.append(f"  {'*' if p['significant'] else ' '} pair {p['name']:30s} -> {p['heldout_gap_after']:.3f} deg "
                 f"({100 * p['heldout_reduction_vs_best_single']:+.1f} % vs its best single, t {p['heldout_t_vs_best_single']:.1f}"
                 f"{rival})")
        _warming_line(L, p)
    if rep.get("structure"):
        L.append("Generic structural discrepancies (an effect must beat the best of these too):")
        for c in rep["structure"]:
            ps = ", ".join(f"{k}={x:.3g}" for k, x in c["params"].items())
            L.append(f"    {c['name']:25s} {c['heldout_gap_before']:.3f} -> {c['heldout_gap_after']:.3f} deg "
                     f"({100 * c['heldout_reduction']:+5.1f} %)  {ps}")
    L.append("")
    v = rep["verdict"]
    L.append(f"Verdict: {', '.join(v) if v else 'no catalogued effect is significant'}")
    for a in rep.get("ambiguous", []):
        rival = "structure" if "heldout_gap_with" in a else "baseline"
        L.append(f"  ambiguous: {a['effect']} vs {rival} {', '.join(a['with'])}: {a['note']}")
    for e in rep.get("effects", []):
        if "still_air" in e:
            L.append(f"  but {e['name']} may be still air: {e['still_air']['note']}")
    if rep.get("measured_currents"):
        L.extend(currents.describe(rep["measured_currents"], indent="  "))
        for e, what in rep.get("verdict_by_currents", {}).items():
            L.append(f"      {e} {what} on the measured currents, whatever the tilt said")
    if rep.get("repeats"):
        L.extend(repeats.describe(rep["repeats"], indent="  "))
        for e, what in rep.get("verdict_by_repeats", {}).items():
            L.append(f"      {e} {what} on the repeated inputs, whatever the tilt said")
    if rep.get("absorption"):
        L.append("What a baseline shift hides of each effect at its catalogue size, on these "
                 "recordings (held out; an effect mostly hidden cannot be told from the baseline "
                 "here, whatever its size in the rig):")
        for a in sorted(rep["absorption"], key=lambda a: -a["absorbed"]):
            by = f"; by {', '.join(a['by'])}" if a["by"] else ""
            L.append(f"    {a['effect']:25s} moves the tilt {a['heldout_size_deg']:.2f} deg, "
                     f"{a['heldout_left_deg']:.2f} deg left ({100 * a['absorbed']:.0f} % hidden{by})"
                     + ("; the thermistors see it: springs not yet powered warm"
                        if a.get("seen_in_temperatures") else ""))
            if a.get("separate"):
                L.append(f"      to tell them apart: {a['separate']}")
    c = rep["corrected"]
    if v:
        for name, ps in c["effects"].items():
            L.append(f"    {name}: " + ", ".join(f"{k} = {x:.4g}" for k, x in ps.items()))
        L.append(f"    held-out gap {n['heldout_gap']:.3f} -> {c['heldout_gap']:.3f} deg "
                 f"({100 * c['heldout_reduction']:.0f} % smaller)")
    x = rep["export"]
    if x["structure"] is not None:
        ps = ", ".join(f"{k} = {v:.3g}" for k, v in x["params"].items())
        shown = (f"the held-out temperatures {x['heldout_T_rms_nominal_C']:.2f} -> "
                 f"{x['heldout_T_rms_structure_C']:.2f} C on the nominal refit (the tilt "
                 f"{x['heldout_gap_nominal_deg']:.3f} -> {x['heldout_gap_structure_deg']:.3f} deg)"
                 if x["evidence"] == "temperatures" else
                 f"held out {x['heldout_gap_nominal_deg']:.3f} -> "
                 f"{x['heldout_gap_structure_deg']:.3f} deg on the nominal refit")
        L.append(f"  the rig's structure, {x['structure']} ({ps}), "
                 + ("is in the exported model" if x["exported"] else "is not exported")
                 + f": {shown}; with the verdict on every recording "
                 f"{x['gap_all_recordings_without_deg']:.3f} -> "
                 f"{x['gap_all_recordings_with_deg']:.3f} deg")
    if x["terminals"] is not None:
        L.append(f"  the terminals' heat path (share {x['terminals']['terminal_share']:.2f}, "
                 f"{x['terminals']['terminal_tau_s']:.0f} s) is in the exported model: the "
                 f"held-out temperatures needed it")
    pr = rep["localization_remaining_pattern"]
    if rep["unexplained"]:
        L.append("UNEXPLAINED: a large residual remains that no catalogued effect explains:")
        for r in rep["unexplained_reasons"]:
            L.append(f"    - {r}")
        L.append(f"    remaining residual: {100 * pr['tilt_share']:.0f} % in the tilt (theta/phi); "
                 f"phase: {pr['concentrated_in_phase']}; trend across recordings "
                 f"{pr['trend_across_recordings']:+.2f}")
        _activation_line(L, pr, "    remaining ", remaining=True)
        for it in rep["localization_remaining"][:3]:
            m = f"muscle {it['muscle']}" if it["muscle"] else "no muscle"
            L.append(f"    remaining: {100 * it['share']:5.1f} % {it['signal']} {it['phase']} {m}")
    else:
        L.append(f"Remaining systematic held-out residual {c['systematic_heldout_residual_deg']:.2f} deg: "
                 "explained")
        if pr.get("concentrated_in_activation") == "several":
            _activation_line(L, pr, "    remaining ", remaining=True)
    if rep.get("outputs"):
        L.append("")
        L.append("Wrote: " + ", ".join(rep["outputs"].values()))
    return "\n".join(L)


# -- plots ----------------------------------------------------------------------------------------

def plots(dg: "D.Diagnosis", stem: Path) -> dict[str, Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from . import localize

    data = dg.data
    out: dict[str, Path] = {}
    res = D.full_residuals(data, dg.full["nominal_heldout"])
    rem = D.full_residuals(data, dg.full["corrected"])

    # 1. residual vs time, all recordings end to end, heating shaded, held-out marked
    fig, axes = plt.subplots(2, 1, figsize=(12, 5.5), sharex=True)
    off = 0.0
    for r, (a, b) in enumerate(zip(res, rem)):
        t = a["t"] + off
        ph, _, _ = localize.phases(a["t"], a["cmd"])
        for ax in axes:
            heat = ph == 0
            ax.fill_between(t, 0, 1, where=heat, transform=ax.get_xaxis_transform(),
                            color="orange", alpha=0.15, lw=0)
            ax.axvline(off, color="0.7", lw=0.5)
        axes[0].plot(t, a["e_theta"], "k", lw=0.7, label="nominal refit" if r == 0 else None)
        axes[1].plot(t, a["e_phi"], "k", lw=0.7)
        if dg.verdict:
            axes[0].plot(t, b["e_theta"], "tab:green", lw=0.7, label="corrected" if r == 0 else None)
            axes[1].plot(t, b["e_phi"], "tab:green", lw=0.7)
        if dg.hold_rec[r]:
            axes[0].text(off + 1, 1.0, "held out", transform=axes[0].get_xaxis_transform(),
                         fontsize=7, va="top", color="tab:blue")
        off = t[-1] + 2.0
    axes[0].set_ylabel("theta residual (deg)")
    axes[1].set_ylabel("phi residual, weighted (deg)")
    axes[1].set_xlabel("time, recordings end to end (s); orange: heating")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("Residual (measured - model) vs time")
    fig.tight_layout()
    p = stem.with_name(stem.name + "_residual_time.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    out["residual_time"] = p

    # 2. residual energy by phase and signal
    fig, ax = plt.subplots(figsize=(6.5, 4))
    sigs = ["theta", "phi", "temperature"]
    colors = {"theta": "tab:blue", "phi": "tab:orange", "temperature": "tab:red"}
    bottoms = np.zeros(3)
    for sgn in sigs:
        vals = np.array([sum(it["share"] for it in dg.localization["items"]
                             if it["signal"] == sgn and it["phase"] == ph) for ph in localize.PHASES])
        if vals.sum() == 0:
            continue
        ax.bar(localize.PHASES, vals, bottom=bottoms, color=colors[sgn], label=sgn)
        bottoms += vals
    tf = dg.localization["phase_time_fraction"]
    ax.plot(localize.PHASES, [tf[p] for p in localize.PHASES], "kD", label="share of time")
    ax.set_ylabel("share of residual energy (nominal refit)")
    ax.set_title("Where the gap lies")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = stem.with_name(stem.name + "_localization.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    out["localization"] = p

    # 3. measured vs nominal vs corrected theta/phi on some recordings (held-out ones first)
    order = list(np.flatnonzero(dg.hold_rec)) + list(np.flatnonzero(~dg.hold_rec))
    show = order[:6]
    fig, axes = plt.subplots(2, len(show), figsize=(3.2 * len(show), 5), squeeze=False)
    for col, r in enumerate(show):
        t = data.t[r] - data.t[r][0]
        nom = dg.full["nominal_heldout"][r]
        cor = dg.full["corrected"][r]
        axes[0, col].plot(t, data.theta[r], "k", lw=1, label="measured")
        axes[0, col].plot(t, nom["theta"], "tab:blue", lw=1, label="nominal")
        axes[0, col].plot(t, cor["theta"], "tab:green", lw=1, ls="--", label="corrected")
        bent = data.theta[r] > 2.0
        axes[1, col].plot(t[bent], data.phi[r][bent], "k.", ms=1)
        nb = nom["theta"] > 2.0
        axes[1, col].plot(t[nb], nom["phi"][nb], "b.", ms=1)
        cb = cor["theta"] > 2.0
        axes[1, col].plot(t[cb], cor["phi"][cb], "g.", ms=1)
        axes[0, col].set_title(f"{data.names[r]}{' (held out)' if dg.hold_rec[r] else ''}", fontsize=8)
        axes[1, col].set_xlabel("t (s)")
    axes[0, 0].set_ylabel("theta (deg)")
    axes[1, 0].set_ylabel("phi (deg), where theta > 2")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("measured (black) vs nominal refit (blue) vs corrected (green)", fontsize=9)
    fig.tight_layout()
    p = stem.with_name(stem.name + "_fit.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    out["fit"] = p
    return out


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_outputs(dg: "D.Diagnosis", json_path: str | Path, dataset_path=None,
                  make_plots: bool = True, extra: dict | None = None) -> dict:
    """Write plots, corrected model files and (last) the JSON report with ``extra`` keys
    added; returns the report."""
    json_path = Path(json_path)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    stem = json_path.with_suffix("")
    outputs: dict[str, str] = {}
    if make_plots:
        for k, p in plots(dg, stem).items():
            outputs[f"plot_{k}"] = str(p)
    exported = dg.exported or dg.final
    params = dg.model.params_of(exported.values, source=f"fitted: neck_env.gap to {dataset_path}")
    p_path = stem.with_name(stem.name + "_params.json")
    tmp = p_path.with_name(p_path.name + ".tmp")
    params.save(tmp)
    os.replace(tmp, p_path)
    outputs["params"] = str(p_path)
    eff = clip_to_catalogue(dg.model.effects_of(exported.setting(), dg.verdict))
    if "convection_change" in eff:
        # the rig as it is now: a draft seen to start during the recordings still blows
        eff["convection_change"]["onset_s"] = 0.0
    e_path = stem.with_name(stem.name + "_effects.json")
    _atomic_write(e_path, json.dumps(eff, indent=2) + "\n")
    outputs["effects"] = str(e_path)
    rep = build_report(dg, dataset_path)
    rep.update(extra or {})
    rep["outputs"] = outputs
    rep["usage"] = ("gymnasium.make('NeckTrack-v0', params=REPORT_params.json path, "
                    "effects=json.load(open(REPORT_effects.json)))")
    _atomic_write(json_path, json.dumps(rep, indent=2) + "\n")
    return rep
