"""How the physics is compiled: one numba configuration for every hot function.

``fastmath`` allows contraction (FMA), reassociation, reciprocal approximation, ignoring the sign
of zero and approximate libm functions -- but not "no NaN / no inf": budgets and supply limits
use ``inf`` as "none", and NaNs must propagate to the checks that reject them.
"""

import os

# Threads that spin while waiting turned a 0.3 ms parallel plant step into 7.5 ms whenever
# another process held a core (measured here while training). Passive waiting costs little when
# the machine is idle and avoids that cliff; an explicit user setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import hashlib  # noqa: E402
from pathlib import Path  # noqa: E402

from numba import njit  # noqa: E402

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}
_PACKAGE = Path(__file__).resolve().parents[1]
_STAMP = _PACKAGE / "physics" / "__pycache__" / "neck_env_sources.sha1"


def _drop_stale_caches() -> None:
    """Delete the package's numba caches when any of its sources changed since they were made.

    numba checks a cached function against its own file only, while the env's step compiles
    the plant (``advance_rig``) and the column layout into it from other files: after an edit
    of ``physics/`` (a new constant column, a new state column) a cached ``envs/core`` step
    would go on running the old physics. In a fresh install nothing is cached and this does
    nothing; a cache that cannot be written (read-only install) is left to numba."""
    h = hashlib.sha1()
    for f in sorted(_PACKAGE.rglob("*.py")):
        h.update(f.relative_to(_PACKAGE).as_posix().encode())
        h.update(f.read_bytes())
    stamp = h.hexdigest()
    try:
        if _STAMP.exists() and _STAMP.read_text() == stamp:
            return
        for f in list(_PACKAGE.rglob("__pycache__/*.nbi")) + list(_PACKAGE.rglob("__pycache__/*.nbc")):
            f.unlink(missing_ok=True)
        _STAMP.parent.mkdir(exist_ok=True)
        _STAMP.write_text(stamp)
    except OSError:
        pass  # another process is at it, or the install is read-only: numba's own checks remain


_drop_stale_caches()


def jit(fn=None, *, parallel: bool = False):
    """``numba.njit`` with the project's cache and fastmath settings."""
    deco = njit(cache=True, fastmath=FASTMATH, parallel=parallel)
    return deco if fn is None else deco(fn)
