"""Record the diagnosis's protocol on the rig as one resumable session (``rig protocol``).

The protocol is ``neck_env.experiments.diagnosis_protocol`` -- the same recordings the synthetic
generator makes and the diagnosis was checked on. For each recording, in protocol order (file
order is recording order: fatigue and drift carry across recordings in that order):

1. the bench supply is set to the recording's current when it changes: by ``supply_cmd`` (a
   programmable supply), by the user at a prompt, or assumed (``yes``);
2. the neck comes to rest (``experiments.REST``): springs within ``REST.temperature_K`` of
   ambient -- the recording's ``start_within_K``, 1 K for the ``rig`` protocol's reference and
   long tails, or no longer cooling -- (thermistors, else the host's estimate, which remembers
   earlier commands on the port) and the tilt within ``REST.tilt_deg`` of the session's rest
   reading, held ``REST.settle_s``; not at rest after ``REST.timeout_s`` is an error;
3. the relay schedule runs through ``HardwareNeckEnv`` (relay mode: its safety -- relays off on
   every error, Ctrl-C and close, the firmware's on-time cap checked before anything runs), its
   edges timed on the host's clock from the recording's first command, and is recorded to
   ``<name>.csv.part``, renamed ``<name>.csv`` only when complete.

Resuming (the same command again): complete recordings are skipped; a ``.part`` file left by an
interrupted recording is moved to ``DIR/interrupted/`` (kept, never read by ``neck-gap``) and the
recording is made again. ``DIR/session.json`` holds the plan and the progress, ``meta.json``
the dataset's metadata (ambient, rate, the rest reading, the protocol).
"""

from __future__ import annotations

import json
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from ..task import DEFAULT_CUTOFF_C, MAX_CURRENT_A
from ..experiments import REST, Recording
from ..recording import META_FILE, RecordingError, check_wire, read_recording
from ..targets import TargetSpec
from .hardware_env import HardwareNeckEnv
from .link import RigLink

__all__ = ["SessionResult", "run_protocol", "SESSION_FILE", "PARTIAL_SUFFIX", "INTERRUPTED_DIR"]

SESSION_FILE = "session.json"
PARTIAL_SUFFIX = ".part"
INTERRUPTED_DIR = "interrupted"
STEP_S = 0.05  # relay schedule resolution: the protocol's edges are on a 50 ms grid or close


@dataclass
class SessionResult:
    """What a (possibly resumed) session did."""

    recorded: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # complete from an earlier run
    moved_aside: list[Path] = field(default_factory=list)  # partial files kept, re-recorded
    rested_s: float = 0.0  # total wait for rest
    elapsed_s: float = 0.0


def _plan(recs: Sequence[Recording], plan_id: dict) -> dict:
    return {**plan_id, "recordings": [
        {"name": r.name, "kind": r.kind, "description": r.description, "supply_A": r.supply_A,
         "duration_s": r.duration_s} for r in recs]}


def _is_complete(path: Path, rec: Recording) -> bool:
    """A recording file that reads and covers the recording's duration (to one step)."""
    try:
        r = read_recording(path)
    except RecordingError:
        return False
    return r.n > 1 and r.t[-1] >= rec.duration_s - 2 * STEP_S


def _move_aside(path: Path, record_dir: Path) -> Path:
    dest_dir = record_dir / INTERRUPTED_DIR
    dest_dir.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    stem = path.name.split(".")[0]
    dest = dest_dir / f"{stem}-{stamp}.csv"
    k = 1
    while dest.exists():
        k += 1
        dest = dest_dir / f"{stem}-{stamp}-{k}.csv"
    path.rename(dest)
    return dest


def _load_session(record_dir: Path, plan: dict) -> dict:
    """The session file of ``record_dir`` (a new one if there is none); refuses a folder that
    holds another protocol or recordings of its own."""
    sf = record_dir / SESSION_FILE
    if sf.is_file():
        try:
            sess = json.loads(sf.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{sf}: unreadable session file ({exc}); record into a new folder") from None
        if sess.get("plan") != plan:
            old = sess.get("plan", {})
            raise ValueError(
                f"{record_dir} holds a session of another protocol (protocol "
                f"{old.get('protocol')!r}, seed {old.get('seed')}, "
                f"{len(old.get('recordings', []))} recordings; this run: {plan['protocol']!r}, "
                f"seed {plan['seed']}, {len(plan['recordings'])} recordings): record into a "
                f"new folder, or repeat that session's options to resume it")
        return sess
    others = sorted(p.name for p in record_dir.glob("*.csv"))
    if others:
        raise ValueError(f"{record_dir} already holds recordings ({', '.join(others[:3])}"
                         f"{', ...' if len(others) > 3 else ''}) that no protocol session made: "
                         f"record into a new folder")
    return {"plan": plan, "rest_tilt_deg": None, "done": {}}


def _save_session(record_dir: Path, sess: dict) -> None:
    tmp = record_dir / (SESSION_FILE + ".tmp")
    tmp.write_text(json.dumps(sess, indent=2) + "\n")
    tmp.replace(record_dir / SESSION_FILE)


def _update_meta(record_dir: Path, sess: dict, wire: Mapping[str, float]) -> None:
    """Add the protocol, the rest reading and the wire to the ``meta.json`` the env wrote."""
    p = record_dir / META_FILE
    meta = json.loads(p.read_text()) if p.is_file() else {}
    meta.update(wire)
    meta["protocol"] = {k: v for k, v in sess["plan"].items()}
    meta["rest_tilt_deg"] = sess["rest_tilt_deg"]
    stuck = {name: d["stuck_at_tilt_deg"] for name, d in sess["done"].items()
             if d.get("stuck_at_tilt_deg") is not None}
    if stuck:  # recordings that started where the backbone held the neck (RestResult.stuck)
        meta["stuck_starts_tilt_deg"] = stuck
    meta["rest_criterion"] = {"tilt_deg": REST.tilt_deg, "temperature_K": REST.temperature_K,
                              "settle_s": REST.settle_s}
    p.write_text(json.dumps(meta, indent=2) + "\n")


def set_supply(amps: float, *, supply_cmd: str | None, yes: bool,
               ask: Callable[[str], str], say: Callable[[str], None]) -> None:
    """Get the bench supply to ``amps``: run ``supply_cmd`` (``{amps}`` replaced), or ask the
    user, or (``yes``) assume it is so. Raises ``RuntimeError`` if the command fails and
    ``KeyboardInterrupt`` if the user stops at the prompt."""
    if supply_cmd:
        cmd = supply_cmd.replace("{amps}", f"{amps:g}")
        say(f"supply: {amps:g} A ({cmd})")
        proc = subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=60)
        if proc.returncode != 0:
            raise RuntimeError(f"--supply-cmd failed (exit {proc.returncode}) setting {amps:g} A: "
                               f"{(proc.stderr or proc.stdout).strip()[-300:]}")
        return
    if yes:
        say(f"supply: {amps:g} A (--yes: not asking; the supply must be at {amps:g} A now)")
        return
    try:
        answer = ask(f"Set the bench supply to {amps:g} A (current limit), then press Enter "
                     f"(q + Enter stops; the session resumes later): ")
    except EOFError:
        raise RuntimeError("no answer at the supply prompt (stdin closed): pass --yes for an "
                           "unattended run or --supply-cmd for a programmable supply") from None
    if answer.strip().lower() in ("q", "quit", "stop"):
        raise KeyboardInterrupt


def run_protocol(link: RigLink, record_dir: str | Path, recordings: Sequence[Recording],
                 plan_id: dict, *, yes: bool = False, supply_cmd: str | None = None,
                 ask: Callable[[str], str] = input, say: Callable[[str], None] = print,
                 thermistors: int = 0, ambient_C: float | None = None, params=None,
                 cutoff_C: float = DEFAULT_CUTOFF_C, stream_hz: int = 100,
                 wire: Mapping[str, float] | None = None) -> SessionResult:
    """Record ``recordings`` into ``record_dir`` (see the module docs); resumes a session.

    ``wire``: ``spring_wire_diameter_m`` and/or ``spring_specific_heat_J_kgK``, written to
    ``meta.json`` for the diagnosis (they turn the fitted cooling time constant into h)."""
    t_start = time.monotonic()
    wire = check_wire(wire or {})
    record_dir = Path(record_dir)
    recs = list(recordings)
    if not recs:
        raise ValueError("the protocol has no recordings")
    cap_s = link.hello.ontime_cap_ms / 1000.0 if link.hello else 10.0
    too_long = [f"{r.name} ({r.longest_on_s:g} s)" for r in recs if r.longest_on_s >= cap_s]
    if too_long:
        raise ValueError(f"recordings keep a relay on for the firmware's on-time cap of "
                         f"{cap_s:g} s or longer: {', '.join(too_long)}")
    too_much = [f"{r.name} ({r.supply_A:g} A)" for r in recs if not 0 < r.supply_A <= MAX_CURRENT_A]
    if too_much:
        raise ValueError(f"supply currents outside (0, {MAX_CURRENT_A:g}] A: {', '.join(too_much)}")
    record_dir.mkdir(parents=True, exist_ok=True)
    plan = _plan(recs, plan_id)
    sess = _load_session(record_dir, plan)
    res = SessionResult()
    todo: list[Recording] = []
    for r in recs:
        final = record_dir / f"{r.name}.csv"
        part = record_dir / f"{r.name}.csv{PARTIAL_SUFFIX}"
        if part.exists():
            res.moved_aside.append(_move_aside(part, record_dir))
        if final.exists():
            if _is_complete(final, r):
                res.skipped.append(r.name)
                continue
            res.moved_aside.append(_move_aside(final, record_dir))  # truncated: kept, redone
        todo.append(r)
    for p in res.moved_aside:
        say(f"kept the interrupted recording as {p} (it is recorded again)")
    if res.skipped:
        say(f"resuming: {len(res.skipped)} of {len(recs)} recordings already complete")
    if not todo:
        if wire:  # given on a resume of a finished session: still recorded with it
            _update_meta(record_dir, sess, wire)
        say("every recording of the protocol is complete")
        res.elapsed_s = time.monotonic() - t_start
        return res
    longest = max(r.duration_s for r in recs)
    env = HardwareNeckEnv(link=link, action_mode="relay", supply_current_A=todo[0].supply_A,
                          energy_budget_J=float("inf"), episode_s=todo[0].duration_s, dt=STEP_S,
                          targets=TargetSpec(first_hold_s=longest + 1.0), thermistors=thermistors,
                          ambient_C=ambient_C, params=params, cutoff_C=cutoff_C,
                          record_dir=record_dir, cooldown_s=REST.timeout_s,
                          cooldown_margin_C=REST.temperature_K, stream_hz=stream_hz, say=say)
    try:
        if env.memory_note:
            say(env.memory_note)
        supply: float | None = None
        for i, r in enumerate(todo):
            if r.supply_A != supply:
                set_supply(r.supply_A, supply_cmd=supply_cmd, yes=yes, ask=ask, say=say)
                supply = r.supply_A
            env.set_episode(supply_current_A=r.supply_A, episode_s=r.duration_s)
            rest = sess["rest_tilt_deg"]
            say(f"{r.name} ({recs.index(r) + 1}/{len(recs)}): {r.description}, {r.duration_s:g} s"
                f" -- waiting for rest first")
            env.reset(seed=0, options={"record_as": f"{r.name}.csv{PARTIAL_SUFFIX}",
                                       "rest_tilt_deg": None if rest is None else tuple(rest),
                                       "require_rest": True,
                                       "start_within_K": r.start_within_K})
            rr = env.last_rest
            res.rested_s += rr.waited_s
            if rest is None:  # the first rest of the session defines its rest reading
                sess["rest_tilt_deg"] = [round(v, 3) for v in rr.rest_tilt_deg]
            _update_meta(record_dir, sess, wire)
            refused = 0
            max_theta = 0.0
            for _ in range(env.task.episode_steps):
                # the plan on the host's clock (``schedule_s``), not the count of steps: a
                # stalled step would otherwise hold a relay on, or off, for the stall's length
                relays = r.relays_at(env.schedule_s())
                _, _, _, trunc, info = env.step(np.array(relays, dtype=np.int8))
                refused |= info["refused"]
                max_theta = max(max_theta, info["theta_deg"])
            path = env.recordings[-1]
            final = record_dir / f"{r.name}.csv"
            path.rename(final)
            sess["done"][r.name] = {"file": final.name, "rested_s": round(rr.waited_s, 1),
                                    "start_excess_K": round(rr.hottest_excess_K, 2),
                                    "finished_unix_s": round(time.time(), 1),
                                    "max_theta_deg": round(max_theta, 2),
                                    "refused_mask": int(refused),
                                    "stuck_at_tilt_deg": ([round(v, 3) for v in rr.rest_tilt_deg]
                                                          if rr.stuck else None)}
            _save_session(record_dir, sess)
            if rr.stuck:
                _update_meta(record_dir, sess, wire)
            res.recorded.append(r.name)
            note = (f"; the firmware held muscles 0b{refused:03b} off at times (safety limits)"
                    if refused else "")
            if rr.stuck:
                note += (f"; started {rr.tilt_off_deg:.2f} deg off the rest reading, where the "
                         f"backbone held the neck (stiction)")
            say(f"{r.name} done: max theta {max_theta:.1f} deg after {rr.waited_s:.0f} s at rest "
                f"wait{note}")
    finally:
        env.close()
    res.elapsed_s = time.monotonic() - t_start
    return res


def describe_plan(recs: Sequence[Recording]) -> str:
    """One paragraph for the user: what will be recorded and roughly how long it takes."""
    total = sum(r.duration_s for r in recs)
    changes = sum(1 for a, b in zip([None] + [r.supply_A for r in recs], [r.supply_A for r in recs])
                  if a != b)
    kinds: dict[str, int] = {}
    for r in recs:
        kinds[r.kind] = kinds.get(r.kind, 0) + 1
    return (f"{len(recs)} recordings ({', '.join(f'{n} {k}' for k, n in kinds.items())}), "
            f"{total / 60:.0f} min of recording plus the waits for rest (~1-2 min after each "
            f"heated recording), {changes} supply setting(s)")

