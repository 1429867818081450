"""``python -m neck_env.rig``: run a policy or controller on the rig, pulse a muscle, inspect.

Subcommands (``--help`` on each explains every flag):

* ``run``   -- episodes of NeckTrack on the rig with a shipped policy (``--policy``) or a
  heuristic controller (``--controller``), recorded to ``--record DIR``; both come from the
  packages registered under the entry-point group ``neck_env.agents`` (``neck_env.agent``:
  this project's ``agents``; ``--policy`` needs the ``[train]`` extra);
* ``pulse`` -- the paper's step experiment: one muscle at the supply current for some seconds,
  then cooling, recorded;
* ``protocol`` -- the recording protocol the diagnosis (``neck-gap``) expects, as one resumable
  session that waits for rest before each recording (``neck_env.rig.session``);
* ``info``  -- firmware identity, safety configuration, live status and faults;
* ``emulate`` -- no hardware: the real firmware in simavr with the simulator as the neck
  (``neck_env.rig.sim_neck.EmulatedRig``); prints the port the other commands take.

Every command switches the relays off when it ends, fails or is interrupted (Ctrl-C); errors
are printed as one line naming the problem, with exit status 1 (2 for bad arguments, 130 for
Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..task import CONTROL_DT_S, DEFAULT_BUDGET_J, DEFAULT_CUTOFF_C, DEFAULT_SUPPLY_A, MAX_CURRENT_A
from ..observation import tilt_angles_deg, tilt_from_accel
from . import protocol as P
from .errors import RigError, fault_names
from ..experiments import RECORDING_PROTOCOLS as PROTOCOL_NAMES
from ..recording import add_wire_arguments, wire_from_arguments

__all__ = ["build_parser", "main"]

def _positive(kind: type, what: str):
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} must be a number, got {text!r}") from None
        if not (math.isfinite(v) and v > 0) and not (kind is float and v == math.inf):
            raise argparse.ArgumentTypeError(f"{what} must be > 0, got {text!r}")
        return v
    return parse


def _mask(text: str) -> int:
    try:
        v = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"thermistor mask must be an integer 0..7 "
                                         f"(e.g. 0b111), got {text!r}") from None
    if not 0 <= v <= 7:
        raise argparse.ArgumentTypeError(f"thermistor mask must be 0..7, got {text!r}")
    return v


def _add_rig_args(p: argparse.ArgumentParser, cooldown_flag: bool = True) -> None:
    p.add_argument("--port", required=True,
                   help="serial port of the UNO (/dev/ttyACM0, COM3) or a pyserial URL "
                        "(socket://host:port, rfc2217://...)")
    p.add_argument("--thermistors", type=_mask, default=0, metavar="MASK",
                   help="NTC thermistors fitted on A0-A2, bit k = muscle k+1 (0b111: all); "
                        "without them the host estimates spring temperatures with the "
                        "simulator's thermal model (default: 0, none)")
    p.add_argument("--ambient", type=float, default=None, metavar="C",
                   help="room temperature for the thermal estimate, deg C (default: the "
                        "model's, 25)")
    p.add_argument("--params", default=None, metavar="JSON",
                   help="model parameters for the thermal estimate and the energy accounting "
                        "(e.g. report_params.json from neck-gap; default: calibrated)")
    if not cooldown_flag:
        return
    p.add_argument("--no-cooldown", action="store_true",
                   help="start at once instead of waiting until the neck is at rest (springs "
                        "near ambient -- measured, or estimated from this computer's earlier "
                        "commands on the port --, tilt steady)")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m neck_env.rig",
        description="The SMA neck rig: run a policy or controller, pulse a muscle, inspect the "
                    "firmware. The relays are switched off when a command ends, fails or is "
                    "interrupted.")
    sub = ap.add_subparsers(dest="command", required=True,
                            metavar="{run,pulse,protocol,info,emulate}")

    r = sub.add_parser("run", help="run NeckTrack episodes on the rig with a policy or controller",
                       description="Episodes of the NeckTrack task on the rig (HardwareNeckEnv), "
                                   "paced in real time, each recorded as rec_NN.csv.")
    who = r.add_mutually_exclusive_group(required=True)
    who.add_argument("--policy", metavar="PATH",
                     help="a deployable policy (NAME.zip with NAME.json beside it, e.g. "
                          "agents/policies/ppo_necktrack.zip)")
    who.add_argument("--controller", metavar="NAME",
                     help="a controller of agents/controllers: zero, open_loop, "
                          "open_loop_lead, bang_bang, pid, mpc")
    _add_rig_args(r)
    r.add_argument("--record", metavar="DIR", default=None,
                   help="folder for the recordings and meta.json (format: "
                        "docs/recording-format.md); read it back with neck-gap DIR (default: "
                        "no recording)")
    r.add_argument("--episodes", type=_positive(int, "--episodes"), default=1,
                   help="number of episodes (default 1)")
    r.add_argument("--episode-s", type=_positive(float, "--episode-s"), default=60.0,
                   metavar="S", help="episode length, s (default 60)")
    r.add_argument("--seed", type=int, default=0,
                   help="seed of the first episode's targets (episode i uses seed + i); the "
                        "same seed gives the same targets as NeckTrack-v0 (default 0)")
    r.add_argument("--supply-current", type=_positive(float, "--supply-current"),
                   default=None, metavar="A",
                   help=f"the bench supply's current setpoint -- set the supply to it (default: "
                        f"the policy's, else {DEFAULT_SUPPLY_A} A)")
    r.add_argument("--action-mode", choices=("current", "relay"), default=None,
                   help="controllers only: duty-switched current levels or plain relays "
                        "(default current; a policy uses the mode it was trained with)")
    r.add_argument("--budget", type=_positive(float, "--budget"), default=DEFAULT_BUDGET_J,
                   metavar="J", help=f"energy budget per episode, J; inf for none "
                                     f"(default {DEFAULT_BUDGET_J:.0f})")
    r.add_argument("--cutoff", type=_positive(float, "--cutoff"), default=DEFAULT_CUTOFF_C,
                   metavar="C", help=f"over-temperature cut, deg C (default {DEFAULT_CUTOFF_C:.0f}, "
                                     f"as in simulation)")
    r.add_argument("--json", metavar="FILE", default=None,
                   help="also write the per-episode summary as JSON")

    q = sub.add_parser("pulse", help="the paper's step experiment: one muscle on, then cooling",
                       description="Relay MUSCLE on for SECONDS at the supply current (set the "
                                   "supply to --current first), then record COOL seconds of "
                                   "cooling. Prints the maximum bending angle (paper Table 1).")
    q.add_argument("--current", type=_positive(float, "--current"), required=True, metavar="A",
                   help=f"the supply current during the pulse, A (paper: 4-8; at most "
                        f"{MAX_CURRENT_A:.0f})")
    q.add_argument("--muscle", type=int, choices=(1, 2, 3), required=True,
                   help="muscle to pulse: 1 (azimuth 180 deg), 2 (60 deg), 3 (300 deg)")
    q.add_argument("--seconds", type=_positive(float, "--seconds"), default=5.0, metavar="S",
                   help="pulse length, s (paper: 5; below the firmware's 10 s on-time cap)")
    q.add_argument("--cool", type=float, default=25.0, metavar="S",
                   help="cooling recorded after the pulse, s (default 25)")
    _add_rig_args(q)
    q.add_argument("--record", metavar="DIR", default=None,
                   help="folder for the recording (format: docs/recording-format.md)")

    s = sub.add_parser(
        "protocol", help="record the diagnosis's protocol (for neck-gap) as a resumable session",
        description="Record the protocol neck-gap expects (neck_env.experiments): pulses at 4-8 A "
                    "on each muscle, relay sequences, cycles and long cooling tails, in order, "
                    "each started at rest (springs near ambient, tilt back at the rest reading; "
                    "waits up to 15 min). Asks you to set the bench supply whenever the current "
                    "changes. Interrupted (Ctrl-C, an error)? Run the same command again: it skips "
                    "complete recordings and redoes the interrupted one (kept in DIR/interrupted).")
    s.add_argument("--record", metavar="DIR", required=True,
                   help="dataset folder (recordings, meta.json, session.json); read it with "
                        "neck-gap DIR")
    s.add_argument("--protocol", choices=PROTOCOL_NAMES, default="rig",
                   help="rig (default: a reference pulse, mixed, two 60 s cooling tails, 18 "
                        "recordings; the reference and muscle 1's tail repeat one input), "
                        "mixed or paper")
    s.add_argument("--seed", type=int, default=0,
                   help="seed of the protocol's order and levels (default 0); resume with the same")
    s.add_argument("--recordings", type=_positive(int, "--recordings"), default=None, metavar="N",
                   help="number of recordings before the cooling tails (default 15; fewer for a "
                        "quick try -- the diagnosis is weaker on few)")
    s.add_argument("--duration", type=_positive(float, "--duration"), default=None, metavar="S",
                   help="length of each recording, s (default 30; at least 8)")
    s.add_argument("--yes", action="store_true",
                   help="do not ask for supply changes (the supply follows on its own, or you "
                        "set it unprompted)")
    s.add_argument("--supply-cmd", metavar="CMD", default=None,
                   help="shell command that sets a programmable supply, {amps} replaced by the "
                        "current (e.g. the emulator's: 'echo {amps} > FILE'); no prompts")
    add_wire_arguments(s)
    s.add_argument("--cutoff", type=_positive(float, "--cutoff"), default=DEFAULT_CUTOFF_C,
                   metavar="C", help=f"over-temperature cut, deg C (default {DEFAULT_CUTOFF_C:.0f})")
    _add_rig_args(s, cooldown_flag=False)

    i = sub.add_parser("info", help="firmware version, safety limits, live status and faults",
                       description="Say hello to the firmware and print its identity, safety "
                                   "configuration and one status sample (relays, faults, IMU).")
    i.add_argument("--port", required=True, help="serial port or pyserial URL of the UNO")
    i.add_argument("--json", action="store_true", help="print JSON instead of text")

    e = sub.add_parser(
        "emulate", help="a rig without hardware: the firmware in simavr, the simulator as neck",
        description="Build the real firmware (make -C firmware; needs the AVR toolchain and "
                    "simavr) and run it in simavr with the simulator playing the neck, in real "
                    "time, until Ctrl-C. Prints the port to pass to the other commands and the "
                    "file that holds the emulated bench supply's current.")
    e.add_argument("--effects", default=None, metavar="NAME[,NAME]|JSON",
                   help="catalogue effects on the emulated neck (neck_env.effects) at their "
                        "typical magnitudes, or a JSON object name -> parameters, e.g. "
                        "'{\"imu_misalignment\": {\"yaw_deg\": 12}}'")
    e.add_argument("--params", default=None, metavar="JSON",
                   help="NeckParams JSON for the emulated neck (default: the calibrated model)")
    e.add_argument("--thermistors", action="store_true",
                   help="fit thermistors on all three springs (pass --thermistors 0b111 to the "
                        "other commands then)")
    e.add_argument("--supply-current", type=_positive(float, "--supply-current"), default=7.0,
                   metavar="A", help="the bench supply's current at start, A (default 7)")
    e.add_argument("--supply-file", default=None, metavar="FILE",
                   help="file holding the supply current (default: a new temporary file)")
    e.add_argument("--seed", type=int, default=0, help="seed of the IMU's noise and biases")
    return ap


# ---------------------------------------------------------------------------------------------


def _open_link(port: str):
    from .link import RigLink

    return RigLink(port)


def cmd_run(args: argparse.Namespace, out=print) -> int:
    from .. import agent as agents  # controllers and policies: the neck_env.agents entry points
    from .hardware_env import HardwareNeckEnv

    pol = agents.load_policy(args.policy) if args.policy else None
    trained = pol.env_kwargs if pol is not None else {}
    if args.policy and args.action_mode is not None and args.action_mode != trained.get(
            "action_mode", "current"):
        raise ValueError(f"--action-mode {args.action_mode}: the policy was trained with "
                         f"{trained.get('action_mode', 'current')!r}")
    mode = trained.get("action_mode", args.action_mode or "current")
    supply = args.supply_current or float(trained.get("supply_current_A", DEFAULT_SUPPLY_A))
    dt = float(trained.get("dt", CONTROL_DT_S))
    env_kwargs = {"action_mode": mode, "dt": dt, "episode_s": args.episode_s,
                  "energy_budget_J": args.budget, "supply_current_A": supply}
    if args.params:
        env_kwargs["params"] = args.params
    agent = pol if pol is not None else agents.make_controller(args.controller, env_kwargs)
    reset_agent, act, label = agent.reset, agent.act, agent.label
    link = _open_link(args.port)
    env = HardwareNeckEnv(link=link, cutoff_C=args.cutoff, thermistors=args.thermistors,
                          ambient_C=args.ambient, record_dir=args.record,
                          cooldown_s=0.0 if args.no_cooldown else 300.0, say=out, **env_kwargs)
    results = []
    try:
        fw = ".".join(map(str, link.hello.fw_version))
        out(f"{label} on {args.port} (firmware {fw}), {mode} mode, supply {supply:g} A, "
            f"{args.episodes} x {args.episode_s:g} s")
        for ep in range(args.episodes):
            seed = args.seed + ep
            obs, info = env.reset(seed=seed)
            reset_agent()
            err, zero, max_T = [], [], float(np.max(info["temperatures_C"]))
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(act(obs))
                err.append(info["tracking_error_deg"])
                zero.append(info["target_theta_deg"])  # doing nothing: the head stays upright
                max_T = max(max_T, float(np.max(info["temperatures_C"])))
                done = term or trunc
            row = {"episode": ep, "seed": seed, "agent": label,
                   "rmse_deg": float(np.sqrt(np.mean(np.square(err)))),
                   "zero_rmse_deg": float(np.sqrt(np.mean(np.square(zero)))),
                   "energy_J": float(info["energy_J"]), "max_temp_C": max_T,
                   "recording": str(env.recordings[-1]) if env.recordings else None}
            results.append(row)
            out(f"episode {ep} (seed {seed}): RMSE {row['rmse_deg']:.2f} deg (doing nothing "
                f"{row['zero_rmse_deg']:.2f}), energy {row['energy_J']:.0f} J, hottest spring "
                f"{max_T:.0f} C" + (f", {row['recording']}" if row["recording"] else ""))
    finally:
        env.close()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0


def cmd_pulse(args: argparse.Namespace, out=print) -> int:
    from .pulse import run_pulse

    if args.current > MAX_CURRENT_A:
        raise ValueError(f"--current {args.current} A exceeds {MAX_CURRENT_A:.0f} A")
    if not (math.isfinite(args.cool) and args.cool >= 0):
        raise ValueError(f"--cool must be >= 0 s, got {args.cool}")
    link = _open_link(args.port)
    try:
        out(f"pulse: muscle {args.muscle} at {args.current:g} A for {args.seconds:g} s, then "
            f"{args.cool:g} s cooling (set the supply to {args.current:g} A)")
        r = run_pulse(link, args.muscle, args.current, args.seconds, args.cool,
                      record_dir=args.record, thermistors=args.thermistors,
                      ambient_C=args.ambient, params=args.params,
                      cooldown=not args.no_cooldown, say=out)
    finally:
        link.close()
    rest = (f"started at rest after {r.rested_s:.0f} s" if not args.no_cooldown
            else "started without waiting for rest (--no-cooldown: if the neck was still bent, "
                 "the maximum may be that earlier bend)")
    out(f"max theta {r.max_theta_deg:.2f} deg at t = {r.t_max_s:.2f} s (phi {r.phi_at_max_deg:.0f} "
        f"deg), spring up to {r.max_temperature_C:.0f} C, {r.energy_J:.0f} J; {rest} (theta "
        f"{r.start_theta_deg:.2f} deg)" + (f"; recorded {r.recording}" if r.recording else ""))
    return 0


def cmd_protocol(args: argparse.Namespace, out=print, ask: Callable[[str], str] = input) -> int:
    from ..experiments import diagnosis_protocol
    from .session import describe_plan, run_protocol

    kw: dict[str, Any] = {}
    if args.recordings is not None:
        kw["n_recordings"] = args.recordings
    if args.duration is not None:
        kw["duration_s"] = args.duration
    recs = diagnosis_protocol(args.seed, args.protocol, **kw)
    plan_id = {"protocol": args.protocol, "seed": args.seed, **kw}
    wire = wire_from_arguments(args)
    link = _open_link(args.port)
    try:
        out(f"protocol {args.protocol!r} (seed {args.seed}) on {args.port} into {args.record}: "
            f"{describe_plan(recs)}")
        res = run_protocol(link, args.record, recs, plan_id, yes=args.yes,
                           supply_cmd=args.supply_cmd, ask=ask, say=out,
                           thermistors=args.thermistors, ambient_C=args.ambient,
                           params=args.params, cutoff_C=args.cutoff, wire=wire)
    finally:
        link.close()
    out(f"protocol complete: {len(res.recorded)} recorded now, {len(res.skipped)} from before, "
        f"{res.elapsed_s / 60:.1f} min ({res.rested_s / 60:.1f} min waiting for rest); "
        f"diagnose with: neck-gap {args.record} --json report.json")
    return 0


def parse_effects(text: str | None) -> dict[str, dict[str, float]]:
    """``--effects``: comma-separated catalogue names (typical magnitudes), a JSON object
    name -> parameters, or a JSON file holding one."""
    from .. import effects as fx

    if not text:
        return {}
    t = text.strip()
    if not t.startswith("{") and t.endswith(".json"):
        t = Path(t).read_text()
    if t.startswith("{"):
        try:
            d = json.loads(t)
        except ValueError as exc:
            raise ValueError(f"--effects: not valid JSON ({exc})") from None
    else:
        d = {n.strip(): {} for n in t.split(",") if n.strip()}
    return fx.check_effects(d)


def cmd_emulate(args: argparse.Namespace, out=print) -> int:
    import threading
    import time

    from ..params import NeckParams
    from .sim_neck import PLANT_DT_US, EmulatedRig
    from .simavr import HarnessUnavailable

    effects = parse_effects(args.effects)
    params = NeckParams.load(args.params) if args.params else None
    # stop cleanly (emulator process too) on Ctrl-C and on kill/SIGTERM, also when started in
    # the background, where a shell leaves SIGINT ignored
    import signal

    def _stop(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, _stop)
    try:
        rig = EmulatedRig(args.supply_current, params=params, effects=effects,
                          thermistors=0b111 if args.thermistors else 0, seed=args.seed,
                          supply_file=args.supply_file)
    except HarnessUnavailable as exc:
        raise RigError(f"cannot build the emulated rig: {exc}. Install the AVR toolchain and "
                       f"simavr (Debian/Ubuntu: apt-get install gcc-avr avr-libc binutils-avr "
                       f"simavr libsimavr-dev arduino-core-avr make gcc), then retry") from None
    try:
        desc = ", ".join(f"{k}({', '.join(f'{p}={v:g}' for p, v in ps.items())})"
                         for k, ps in effects.items()) or "none"
        out(f"emulated rig running (firmware in simavr, simulated neck; effects: {desc}"
            f"{'; thermistors on A0-A2' if args.thermistors else ''})")
        out(f"port: {rig.port}")
        out(f"bench supply: {rig.supply_current_A:g} A, set with: echo AMPS > {rig.supply_file}")
        out(f"  e.g. python -m neck_env.rig protocol --port {rig.port} --record DIR "
            f"--supply-cmd 'echo {{amps}} > {rig.supply_file}'")
        out("Ctrl-C stops it")
        sys.stdout.flush()  # a script reading the port from a pipe sees it now
        shown = None
        while True:
            rig.check()
            if rig.supply_error != shown:
                shown = rig.supply_error
                if shown:
                    out(f"supply file ignored: {shown}")
            time.sleep(0.2)
    finally:
        try:
            age_ms = rig.harness.stats()["imu_age_max_us"] / 1000.0
            out(f"the firmware's IMU reads were at most {age_ms:.0f} ms old (the simulated neck's "
                f"{PLANT_DT_US / 1000:g} ms steps; more: it fell behind, a busy machine)")
        except Exception:  # noqa: BLE001 - a summary only; the emulator may already be gone
            pass
        rig.close()


def info_dict(link) -> dict[str, Any]:
    """Identity, configuration and one status sample as plain data (for ``info``)."""
    h = link.hello
    st = link.status()
    ax, ay, az = (v / P.ACCEL_LSB_PER_G for v in st.accel)
    tx, ty = tilt_from_accel(ax, ay, az)
    theta, phi = tilt_angles_deg(tx, ty)
    imu_ok = not (st.faults & P.Fault.imu_any())
    return {
        "port": link.port,
        "protocol_version": h.protocol_version,
        "firmware_version": ".".join(map(str, h.fw_version)),
        "relay_pins": list(h.relay_pins),
        "limits": {"heartbeat_timeout_ms": h.heartbeat_timeout_ms,
                   "ontime_cap_ms": h.ontime_cap_ms, "lockout_ms": h.lockout_ms,
                   "duty_window_ms": h.duty_window_ms, "duty_max_permille": h.duty_max_permille,
                   "over_temperature_cut_C": round(P.ntc_adc_to_celsius(h.therm_cut_adc), 1),
                   "over_temperature_release_C": round(P.ntc_adc_to_celsius(h.therm_release_adc), 1),
                   # what the cut above means: the firmware's own default until a host's CONFIG
                   "firmware_default_cut_C": FIRMWARE_DEFAULT_CUT_C,
                   "host_cutoff_C": DEFAULT_CUTOFF_C},
        "status": {"mcu_time_s": st.t_ms / 1000.0, "relays": st.relays, "blocked": st.blocked,
                   "faults": fault_names(st.faults), "bad_frames": st.bad_frames,
                   "watchdog_trips": st.wdt_trips, "imu_errors": st.imu_errors,
                   "thermistor_mask": st.thermistor_mask,
                   "thermistors_C": [None if not math.isfinite(c := P.ntc_adc_to_celsius(a))
                                     else round(c, 1) for a in st.thermistors]},
        "imu": {"ok": imu_ok, "accel_g": [round(v, 4) for v in (ax, ay, az)],
                "gyro_dps": [round(v / P.GYRO_LSB_PER_DPS, 3) for v in st.gyro],
                "tilt_theta_deg": round(float(theta), 2) if imu_ok else None,
                "tilt_phi_deg": round(float(phi), 1) if imu_ok else None},
        "boots_seen": len(link.boots),
    }


def cmd_info(args: argparse.Namespace, out=print) -> int:
    link = _open_link(args.port)
    try:
        d = info_dict(link)
    finally:
        link.close()
    if args.json:
        out(json.dumps(d, indent=2))
        return 0
    lim, st, imu = d["limits"], d["status"], d["imu"]
    out(f"{d['port']}: neck firmware {d['firmware_version']}, protocol {d['protocol_version']}, "
        f"relays on pins {d['relay_pins']}")
    out(f"safety: heartbeat {lim['heartbeat_timeout_ms']} ms, on-time cap "
        f"{lim['ontime_cap_ms'] / 1000:g} s (lock-out {lim['lockout_ms'] / 1000:g} s), duty "
        f"<= {lim['duty_max_permille'] / 10:g} % of {lim['duty_window_ms']} ms, "
        f"over-temperature cut {lim['over_temperature_cut_C']} C (release "
        f"{lim['over_temperature_release_C']} C)")
    out(f"  (the cut above is what the firmware holds now: {FIRMWARE_DEFAULT_CUT_C:.0f} C is its "
        f"default until a host configures it. run/pulse/protocol set it to --cutoff, default "
        f"{DEFAULT_CUTOFF_C:.0f} C, when thermistors are fitted; without thermistors the host "
        f"cuts at --cutoff on its thermal estimate)")
    out(f"status: relays 0b{st['relays']:03b}, faults {', '.join(st['faults']) or 'none'}, "
        f"bad frames {st['bad_frames']}, watchdog trips {st['watchdog_trips']}, MCU up "
        f"{st['mcu_time_s']:.1f} s")
    if imu["ok"]:
        out(f"IMU: accel {imu['accel_g']} g, gyro {imu['gyro_dps']} deg/s, tilt "
            f"{imu['tilt_theta_deg']} deg toward {imu['tilt_phi_deg']} deg")
    else:
        out("IMU: NOT OK (" + ", ".join(f for f in st["faults"] if f.startswith("IMU")) +
            "): check the MPU6050 wiring (SDA A4, SCL A5, 0x68)")
    out(f"thermistors (mask 0b{st['thermistor_mask']:03b}): {st['thermistors_C']} C")
    return 0


COMMANDS = {"run": cmd_run, "pulse": cmd_pulse, "protocol": cmd_protocol, "info": cmd_info,
            "emulate": cmd_emulate}
FIRMWARE_DEFAULT_CUT_C = 110.0  # firmware/src/config.h THERM_CUT_ADC default, before CONFIG


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print("emulator stopped" if args.command == "emulate" else
              "interrupted: relays commanded off", file=sys.stderr)
        return 130
    except (RigError, RuntimeError, ValueError, FileNotFoundError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
