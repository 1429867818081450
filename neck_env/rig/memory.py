"""What the host remembers of a rig between commands: its springs' thermal state.

Without thermistors the host knows the springs' temperatures only from its thermal estimate
(``ThermalEstimate``), which a fresh process would start at ambient. Two ``rig pulse`` runs a
minute apart would then both believe the springs cold, and the second would record a neck
still bent by the first. So every command that drives a rig saves the estimate's state with
the wall-clock time to a small JSON file per port, and the next command on that port restores
it and integrates the cooling over the time in between (relays off meanwhile: the firmware
switches them off 250 ms after its host goes silent).

Where: ``$NECK_RIG_STATE_DIR`` if set, else the user state directory
(``~/.local/state/neck_env/rigs`` on Linux, via ``platformdirs`` where installed). A file older
than :data:`COLD_AFTER_S` is as good as none (the springs are long cold); a file that cannot be
read is reported and ignored, never fatal.
"""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

from .thermal_estimate import ThermalEstimate

__all__ = ["RigMemory", "state_dir", "COLD_AFTER_S"]

STATE_ENV = "NECK_RIG_STATE_DIR"
COLD_AFTER_S = 1800.0  # idle this long the model's springs are at ambient to < 0.01 K
VERSION = 1


def state_dir() -> Path:
    """Folder of the per-rig state files."""
    env = os.environ.get(STATE_ENV)
    if env:
        return Path(env)
    try:
        from platformdirs import user_state_dir

        return Path(user_state_dir("neck_env")) / "rigs"
    except ImportError:
        base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
        return Path(base) / "neck_env" / "rigs"


class RigMemory:
    """The saved thermal state of the rig on ``port``."""

    def __init__(self, port: str, directory: str | os.PathLike[str] | None = None) -> None:
        self.port = str(port)
        key = re.sub(r"[^A-Za-z0-9._-]+", "_", self.port).strip("_") or "rig"
        self.path = Path(directory) if directory is not None else state_dir()
        self.path = self.path / f"{key}.json"

    def restore(self, estimate: ThermalEstimate, now_unix_s: float | None = None) -> str:
        """Load the saved state into ``estimate`` and cool it over the time since it was saved.
        Returns one line saying what was assumed (for the user)."""
        now = time.time() if now_unix_s is None else now_unix_s
        if not self.path.is_file():
            return (f"no earlier use of {self.port} recorded on this computer: taking the springs "
                    f"as at ambient")
        try:
            d = json.loads(self.path.read_text())
            saved = float(d["saved_unix_s"])
            idle = now - saved
            if d.get("version") != VERSION or idle < -5.0:
                raise ValueError("unknown version or a save time in the future")
            if idle >= COLD_AFTER_S:
                return f"{self.port} idle for {idle / 60:.0f} min: springs at ambient"
            estimate.load_state_vector(d["state"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            return f"ignored unreadable rig state {self.path} ({exc}): taking the springs as at ambient"
        # relays were off while no host ran (the firmware's heartbeat watchdog)
        estimate.advance([0.0, 0.0, 0.0], max(idle, 0.0))
        hottest = float(max(estimate.temperatures_C))
        return (f"{self.port} last driven {idle:.0f} s ago: springs estimated at up to "
                f"{hottest:.0f} C now")

    def save(self, estimate: ThermalEstimate, now_unix_s: float | None = None) -> None:
        """Write the estimate's state now (atomically; a failure to write is not an error of
        the rig: it is ignored, the next command then waits as for an unknown rig)."""
        now = time.time() if now_unix_s is None else now_unix_s
        d = {"version": VERSION, "port": self.port, "saved_unix_s": now,
             "ambient_C": estimate.ambient_C,
             "temperatures_C": [round(float(v), 3) for v in estimate.temperatures_C],
             "state": estimate.state_vector()}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(json.dumps(d) + "\n")
            os.replace(tmp, self.path)
        except OSError:
            pass
