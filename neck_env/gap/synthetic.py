"""Synthetic "real" datasets: the paper's experiments run on a perturbed simulator with effects.

    python -m neck_env.gap.synthetic OUT_DIR --effects imu_misalignment[,sma_fatigue] --seed 3

writes ``OUT_DIR/rec_01.csv ...`` and ``OUT_DIR/meta.json`` in the recording format of
``neck_env.recording`` and the ground truth to ``OUT_DIR.truth.json`` **beside** the folder
(``--truth`` to put it elsewhere): the diagnosis reads only the folder, never the truth.

What a dataset holds (protocol ``mixed``, the default; ~15 recordings of 30 s at 50 Hz):

* single-muscle pulses: one muscle at 4-8 A for 5 s from t = 2 s, then cooling (9 recordings,
  each muscle three times, currents spread over 4-8 A),
* multi-muscle relay sequences at one supply current (5.5-7 A): relays switched every 2-3.5 s
  among single muscles and pairs for ~14 s, then cooling (3 recordings),
* repeated cycles: one muscle at 5-6 A, 3 s on / 4 s off, three times (3 recordings),

in a shuffled order. Protocol ``paper``: the paper's own experiments (5 s pulses at 4, 4.25,
4.5, 4.75, 5 A -- its Fig. 7 -- and 6, 7, 8 A -- its Table 1 -- on the three muscles).

How the "real" rig differs from the nominal model:

* parameters: the calibrated ones (convection, transformation temperatures, stress
  coefficient, bending stiffness, recoverable strain) perturbed by a few per cent (shift of
  +-1.5 C), ambient 20-28 C (meta.json reports it to +-0.3 C),
* integration: the plant runs at 10 ms (the diagnosis simulates at 20 ms),
* sensors: an MPU6050 model -- accelerometer and gyro readings of the head pose (through the
  IMU mount), per-dataset biases and white noise (``SensorParams``) -- fused by the rig's own
  complementary filter at 50 Hz (the project's sensor chain, ``sensors.imu_tilt_series``);
  theta/phi come from that tilt;
  thermistor noise on T1..T3 when temperatures are recorded (random per dataset unless given),
* effects (zero, one or two) with magnitudes drawn uniformly in their catalogue ranges (or
  given): plant effects through ``effects.apply_to_constants``, ``imu_misalignment`` through
  the mount, ``actuation_delay`` shifts the applied currents, ``gyro_bias_drift`` adds a gyro
  bias growing with the dataset's recorded time, ``sma_fatigue`` carries the springs' fatigue
  from recording to recording (file order). Every recording starts at rest (the rig cooled
  down between recordings); only effects that build up over use carry over. With
  ``--starts cooled`` the whole state carries over through a simulated wait for rest (relays
  off until the springs are within 3 K of ambient, then 20 s), as the rig's protocol records:
  a backbone with friction then holds the neck off upright at the next start.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .. import effects as fx
from ..params import NeckParams, default_params
from ..physics import layout as L
from ..physics.plant import (constants_from_params, cooling_time_constant_s, initial_state,
                             step_inplace)
from ..experiments import (REST, RestCriterion, add_dataset_arguments, dataset_arguments,
                           diagnosis_protocol, simulated_wait, truth_path_for)
from ..recording import write_meta, write_recording
from . import currents
from ..sensors import SensorParams, imu_tilt_series

GEN_DT_S = 0.01


# -- generation ------------------------------------------------------------------------------------

BASELINES = ("default", "wide")


def wide_params(rng: np.random.Generator, base: NeckParams | None = None) -> NeckParams:
    """A rig whose baseline is far from the defaults (issue 11's spread): convection x0.3-x4 and
    stress coefficient x0.5-x3 (log-uniform), transformation temperatures +-15 C, bending
    stiffness x0.5-x2 (log-uniform), recoverable strain x0.7-x1.4, resistivity and specific
    heat +-20 %, ambient 15-35 C."""
    b = base or default_params()
    m = b.material
    logu = lambda lo, hi: float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    h, ca, ei = logu(0.3, 4.0), logu(0.5, 3.0), logu(0.5, 2.0)
    gl, sh = float(rng.uniform(0.7, 1.4)), float(rng.uniform(-15.0, 15.0))
    rho, cp = float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.8, 1.2))
    return b.replace(
        source="synthetic: wide baseline",
        thermal__convection_W_m2K=b.thermal.convection_W_m2K * h,
        thermal__ambient_C=float(rng.uniform(15.0, 35.0)),
        material__As_C=m.As_C + sh, material__Af_C=m.Af_C + sh,
        material__Ms_C=m.Ms_C + sh, material__Mf_C=m.Mf_C + sh,
        material__C_A_Pa_per_K=m.C_A_Pa_per_K * ca, material__C_M_Pa_per_K=m.C_M_Pa_per_K * ca,
        material__resistivity_martensite_ohm_m=m.resistivity_martensite_ohm_m * rho,
        material__resistivity_austenite_ohm_m=m.resistivity_austenite_ohm_m * rho,
        material__specific_heat_J_kgK=m.specific_heat_J_kgK * cp,
        backbone__bending_stiffness_Nm2=b.backbone.bending_stiffness_Nm2 * ei,
        spring__recoverable_shear_strain=b.spring.recoverable_shear_strain * gl,
    )


def sample_effect(name: str, rng: np.random.Generator, dataset_s: float) -> dict[str, float]:
    """Magnitudes of one effect as the generators draw them.

    ``convection_change`` is drawn as what no constant h produces (a constant gain is a
    different baseline h): half the time h grows with temperature (0.004-0.012 /K), half the
    time a draft (h x1.8-2.5 or x0.4-0.55) starts between 30 % and 70 % of the dataset's
    recorded time ``dataset_s``."""
    if name != "convection_change":
        return fx.EFFECTS[name].sample(rng)
    if rng.random() < 0.5:
        return {"gain": 1.0, "tcoef_per_K": float(rng.uniform(0.004, 0.012)), "onset_s": 0.0}
    gain = float(rng.uniform(1.8, 2.5)) if rng.random() < 0.5 else float(rng.uniform(0.4, 0.55))
    return {"gain": gain, "tcoef_per_K": 0.0,
            "onset_s": float(round(rng.uniform(0.3, 0.7) * dataset_s, 3))}


def perturbed_params(rng: np.random.Generator, base: NeckParams | None = None,
                     jitter: float = 0.05, shift_C: float = 1.5,
                     ambient_C: tuple[float, float] = (20.0, 28.0),
                     hard: bool = False) -> NeckParams:
    """The calibrated parameters perturbed by a few per cent (the "real" rig's own values).

    ``hard``: a rig further from the model -- the fitted parameters by +-15 % (+-3 C), and the
    ones the diagnosis never fits (heat capacity, resistivity, latent heat, moduli, geometry,
    damping, torsion, pre-tension) by a few per cent too."""
    b = base or default_params()
    if hard:
        jitter, shift_C = max(jitter, 0.15), max(shift_C, 3.0)
    f = lambda j=jitter: float(rng.uniform(1 - j, 1 + j))
    sh = float(rng.uniform(-shift_C, shift_C))
    m = b.material
    ca = f()
    p = b.replace(
        source="synthetic: perturbed calibrated value",
        thermal__convection_W_m2K=b.thermal.convection_W_m2K * f(),
        thermal__ambient_C=float(rng.uniform(*ambient_C)),
        material__As_C=m.As_C + sh, material__Af_C=m.Af_C + sh,
        material__Ms_C=m.Ms_C + sh, material__Mf_C=m.Mf_C + sh,
        material__C_A_Pa_per_K=m.C_A_Pa_per_K * ca, material__C_M_Pa_per_K=m.C_M_Pa_per_K * ca,
        backbone__bending_stiffness_Nm2=b.backbone.bending_stiffness_Nm2 * f(),
        spring__recoverable_shear_strain=b.spring.recoverable_shear_strain * f(),
    )
    if hard:
        rho = f(0.05)
        p = p.replace(
            source="synthetic: perturbed unfitted value",
            material__specific_heat_J_kgK=m.specific_heat_J_kgK * f(0.05),
            material__resistivity_martensite_ohm_m=m.resistivity_martensite_ohm_m * rho,
            material__resistivity_austenite_ohm_m=m.resistivity_austenite_ohm_m * rho * f(0.02),
            material__latent_heat_J_kg=m.latent_heat_J_kg * f(0.1),
            material__youngs_austenite_Pa=m.youngs_austenite_Pa * f(0.05),
            material__youngs_martensite_Pa=m.youngs_martensite_Pa * f(0.05),
            material__Af_C=p.material.Af_C + float(rng.uniform(-1.0, 1.0)),
            material__Mf_C=p.material.Mf_C + float(rng.uniform(-1.0, 1.0)),
            muscles__pennation_deg=b.muscles.pennation_deg + float(rng.uniform(-1.5, 1.5)),
            muscles__head_radius_m=b.muscles.head_radius_m * f(0.03),
            backbone__damping_Nms_per_rad=b.backbone.damping_Nms_per_rad * f(0.3),
            backbone__torsional_stiffness_Nm2=b.backbone.torsional_stiffness_Nm2 * f(0.2),
            spring__pretension_extension_m=b.spring.pretension_extension_m * f(0.1),
        )
    return p


def resolve_effects(effects, rng: np.random.Generator,
                    dataset_s: float = 450.0) -> dict[str, dict[str, float]]:
    """Names (magnitudes drawn in range, ``sample_effect``) or a mapping name -> (partial)
    parameters."""
    if effects is None:
        return {}
    if isinstance(effects, str):
        effects = [e for e in effects.split(",") if e.strip() and e.strip() != "none"]
    if isinstance(effects, Mapping):
        out = {}
        for name, given in effects.items():
            if name not in fx.EFFECTS:
                raise ValueError(f"unknown effect {name!r}; known: {sorted(fx.EFFECTS)}")
            vals = sample_effect(name, rng, dataset_s)
            vals.update(given or {})
            out[name] = fx.EFFECTS[name].check(vals)
        return out
    out = {}
    for name in effects:
        name = name.strip()
        if name not in fx.EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {sorted(fx.EFFECTS)}")
        out[name] = sample_effect(name, rng, dataset_s)
    return out


STARTS = ("upright", "cooled")


def _cooled(consts: np.ndarray, x: np.ndarray, dt: float,
            criterion: RestCriterion = REST) -> np.ndarray:
    """The state after the rig protocol's wait for the rest ``criterion`` from ``x``
    (``simulated_wait``)."""
    x = x.copy()
    left = np.full(1, np.inf)
    o = np.empty((1, L.N_OUT))
    off = np.zeros((1, 3))
    amb = consts[0, L.AMBIENT]

    def advance(seconds: float) -> float:
        n = max(1, int(round(seconds / dt)))
        step_inplace(consts, x, off, dt, n, left, o)
        return n * dt

    simulated_wait(advance, lambda: float(np.max(x[0, L.S_T:L.S_T + 3] - amb)),
                   criterion=criterion)
    return x


def generate(out_dir: str | Path, effects=None, seed: int = 0, protocol: str = "mixed",
             n_recordings: int = 15, duration_s: float = 30.0, sample_hz: float = 50.0,
             temperatures: bool | None = None, jitter: float = 0.05,
             truth_path: str | Path | None = None, sensors: SensorParams | None = None,
             write_meta_file: bool = True, hard: bool = False, baseline: str = "default",
             wire_meta: bool = True, switched_off: bool = False,
             current_sensor: bool = False, starts: str = "upright") -> dict:
    """Write a synthetic dataset to ``out_dir`` and its truth beside it; returns the truth.

    ``starts``: ``upright`` (every recording starts upright with cold springs, as if the neck
    were reset between recordings) or ``cooled`` (as the rig's protocol records: between
    recordings the relays stay off until every spring is within ``REST.temperature_K`` of
    ambient and then ``REST.stuck_s`` longer, and the next recording starts from that state --
    upright again, unless the backbone's friction holds the neck off it).

    ``switched_off``: the effects are drawn (so that every later draw -- protocol, biases,
    noise -- is the same) but not simulated: the same rig, protocol and noise without them,
    against which a benchmark measures how much an effect moves the data.

    ``current_sensor``: the recordings also hold ``i1_meas..i3_meas``, a Hall sensor's reading of
    the current that flowed (``currents.HallSensor``; drawn from a generator of its own, so
    every other column is the same as without it).

    ``wire_meta``: meta.json gives the wire as its builder knows it: the diameter, and the
    specific heat of the datasheet (the defaults'), not this rig's drawn one.

    ``baseline``: ``default`` (the calibrated values perturbed by a few per cent) or ``wide``
    (a rig far from the defaults, ``wide_params``). ``hard``: a rig further from the model
    (see ``perturbed_params``), integrated at 5 ms, with 1.5x the sensor noise and biases."""
    out_dir = Path(out_dir)
    if baseline not in BASELINES:
        raise ValueError(f"unknown baseline {baseline!r}; known: {BASELINES}")
    if starts not in STARTS:
        raise ValueError(f"unknown starts {starts!r}; known: {STARTS}")
    rng = np.random.default_rng(seed)
    params = perturbed_params(rng, jitter=jitter, hard=hard)
    if baseline == "wide":
        params = wide_params(rng)
    drawn = resolve_effects(effects, rng, dataset_s=n_recordings * duration_s)
    eff = {} if switched_off else drawn
    if temperatures is None:
        temperatures = bool(rng.integers(2))
    if sensors is None:
        sensors = SensorParams()
        if hard:
            sensors = SensorParams(**{k: 1.5 * v for k, v in sensors.__dict__.items()})
    recs = diagnosis_protocol(rng, protocol, n_recordings, duration_s)

    consts = constants_from_params(params)
    consts = fx.apply_to_constants(consts, {k: v for k, v in eff.items()
                                            if fx.EFFECTS[k].kind == "plant"})
    draft = eff.get("convection_change", {})
    draft_onset = float(draft.get("onset_s", 0.0))
    consts_before = consts.copy()
    if draft_onset > 0:
        consts_before[:, L.CONV_GAIN] = 1.0
    mount = fx.imu_mount(eff)
    delay = fx.delay_s(eff)
    drift_rate = fx.gyro_drift(eff)
    sensor_rng = np.random.default_rng([seed, 1])  # its own: the other columns stay the same
    sensor = currents.HallSensor.draw(sensor_rng)
    abias = rng.normal(0.0, sensors.accel_bias_g, 3)
    gbias = rng.normal(0.0, sensors.gyro_bias_dps, 3)

    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("*.csv"):
        old.unlink()
    sub = max(1, int(round(1.0 / (sample_hz * (GEN_DT_S / 2 if hard else GEN_DT_S)))))
    dt = 1.0 / (sample_hz * sub)
    fatigue = np.zeros(3)
    t_cum = 0.0
    recs_truth = []
    width = max(2, len(str(len(recs))))
    for r, rec in enumerate(recs):
        desc = rec.description
        t = rec.sample_times(sample_hz)
        cmd = rec.currents(t)
        n = t.size
        steps = (n - 1) * sub
        # applied currents on the fine grid: zero-order hold of the command, delayed
        fine_t = np.arange(steps) * dt
        src_t = fine_t - delay
        j = np.floor(src_t * sample_hz + 1e-9).astype(int)
        applied = np.where((j >= 0)[:, None], cmd[np.clip(j, 0, n - 1)], 0.0)
        rc = consts if t_cum >= draft_onset else consts_before
        if starts == "cooled" and r > 0:
            x = _cooled(rc, x, dt, rec.rest)
        else:
            x = initial_state(rc)
            x[0, L.S_FATIGUE:L.S_FATIGUE + 3] = fatigue
        left = np.full(1, np.inf)
        o = np.empty((1, L.N_OUT))
        qs = np.empty((n, 3))
        Ts = np.empty((n, 3))
        flowing = np.zeros((n, 3))  # at each sample instant: the step that starts there
        qs[0] = x[0, L.S_Q:L.S_Q + 3]
        Ts[0] = x[0, L.S_T:L.S_T + 3]
        for k in range(steps):
            step_inplace(rc, x, np.ascontiguousarray(applied[k:k + 1]), dt, 1, left, o)
            if k % sub == 0:
                flowing[k // sub] = o[0, L.O_CURRENT:L.O_CURRENT + 3]
            if (k + 1) % sub == 0:
                qs[(k + 1) // sub] = x[0, L.S_Q:L.S_Q + 3]
                Ts[(k + 1) // sub] = x[0, L.S_T:L.S_T + 3]
        fatigue = x[0, L.S_FATIGUE:L.S_FATIGUE + 3].copy()
        if n > 1:
            flowing[-1] = flowing[-2]
        tilt = np.empty((n, 2))
        a_noise = rng.normal(0.0, sensors.accel_noise_g, (n, 3))
        g_noise = rng.normal(0.0, sensors.gyro_noise_dps, (n, 2))
        imu_tilt_series(np.ascontiguousarray(qs), 1.0 / sample_hz, np.ascontiguousarray(mount),
                        abias, gbias, drift_rate * t_cum, drift_rate, a_noise, g_noise, tilt)
        cols = {"t": t, "i1": cmd[:, 0], "i2": cmd[:, 1], "i3": cmd[:, 2],
                "theta_deg": np.hypot(tilt[:, 0], tilt[:, 1]),
                "phi_deg": np.mod(np.degrees(np.arctan2(tilt[:, 1], tilt[:, 0])), 360.0)}
        if temperatures:
            Tm = Ts + rng.normal(0.0, sensors.temperature_noise_C, Ts.shape)
            cols.update({"T1": Tm[:, 0], "T2": Tm[:, 1], "T3": Tm[:, 2]})
        if current_sensor:
            cols.update(sensor.columns(flowing, sensor_rng))
        name = f"rec_{r + 1:0{width}d}.csv"
        write_recording(out_dir / name, cols)
        true_theta = np.degrees(np.hypot(qs[:, 0], qs[:, 1]))
        recs_truth.append({"file": name, "protocol": desc, "t_start_s": t_cum,
                           "peak_T_C": float(Ts.max()), "max_true_theta_deg": float(true_theta.max()),
                           "fatigue_end": fatigue.tolist(),
                           "start_true_tilt_deg": np.degrees(qs[0, :2]).tolist()})
        t_cum += t[-1]
    meta = {"ambient_C": round(params.thermal.ambient_C + float(rng.normal(0.0, 0.3)), 1),
            "sample_hz": sample_hz, "muscle_azimuth_deg": list(params.muscles.azimuths_deg)}
    if wire_meta:
        meta.update(spring_wire_diameter_m=params.spring.wire_diameter_m,
                    spring_specific_heat_J_kgK=default_params().material.specific_heat_J_kgK)
    if write_meta_file:
        write_meta(out_dir, meta)
    truth = {
        "generator": "neck_env.gap.synthetic", "seed": seed, "protocol": protocol,
        "effects": eff, "effect_names": sorted(eff),
        **({"drawn_effects_switched_off": drawn} if switched_off else {}),
        "catalogued": sorted(k for k in eff if fx.EFFECTS[k].in_catalogue),
        "temperatures": temperatures, "params": params.to_dict(),
        "sensor_bias": {"accel_g": abias.tolist(), "gyro_dps": gbias.tolist()},
        "recordings": recs_truth, "meta": meta, "integrator_dt_s": dt, "hard": hard,
        "current_sensor": current_sensor,
        "baseline": baseline, "baseline_ratios": baseline_ratios(params), "starts": starts,
        "physical": {"convection_W_m2K": params.thermal.convection_W_m2K,
                     "cooling_time_constant_s": cooling_time_constant_s(params)},
    }
    tp = Path(truth_path) if truth_path is not None else truth_path_for(out_dir)
    tp.parent.mkdir(parents=True, exist_ok=True)
    tp.write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def baseline_ratios(params: NeckParams) -> dict[str, float]:
    """The rig's baseline against the defaults, in the diagnosis's own terms."""
    d = default_params()
    return {
        "h_scale": params.thermal.convection_W_m2K / d.thermal.convection_W_m2K,
        "As_shift_C": params.material.As_C - d.material.As_C,
        "CA_scale": params.material.C_A_Pa_per_K / d.material.C_A_Pa_per_K,
        "EI_scale": params.backbone.bending_stiffness_Nm2 / d.backbone.bending_stiffness_Nm2,
        "gammaL_scale": params.spring.recoverable_shear_strain / d.spring.recoverable_shear_strain,
        "EM_scale": params.material.youngs_martensite_Pa / d.material.youngs_martensite_Pa,
        "R_scale": (params.material.resistivity_martensite_ohm_m
                    / d.material.resistivity_martensite_ohm_m),
        "heat_capacity_scale": params.material.specific_heat_J_kgK / d.material.specific_heat_J_kgK,
        "ambient_C": params.thermal.ambient_C,
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neck_env.gap.synthetic", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir", help="dataset folder to write (its *.csv are replaced)")
    add_dataset_arguments(ap, list(fx.EFFECTS))
    ap.add_argument("--hard", action="store_true", help="a rig further from the model: larger "
                    "parameter spread, unfitted parameters perturbed, 5 ms integration, more "
                    "sensor noise")
    ap.add_argument("--baseline", choices=BASELINES, default="default",
                    help="default: the calibrated rig perturbed by a few per cent; wide: a rig "
                         "far from the defaults (h x0.3-x4, transformation temperatures +-15 C, "
                         "EI x0.5-x2, C_A x0.5-x3, ...)")
    ap.add_argument("--starts", choices=STARTS, default="upright",
                    help="upright: every recording starts upright (the neck reset between "
                         "recordings); cooled: from where the rig's wait for rest leaves it "
                         "(a backbone with friction holds it off upright)")
    args = ap.parse_args(argv)
    try:
        effects, kwargs = dataset_arguments(args)
        truth = generate(args.out_dir, effects, hard=args.hard, baseline=args.baseline,
                         starts=args.starts, **kwargs)
    except (ValueError, json.JSONDecodeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    tp = args.truth or truth_path_for(args.out_dir)
    print(f"wrote {len(truth['recordings'])} recordings to {args.out_dir} "
          f"(effects: {', '.join(truth['effect_names']) or 'none'}; truth: {tp})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
