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

from numba import njit  # noqa: E402

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


def jit(fn=None, *, parallel: bool = False):
    """``numba.njit`` with the project's cache and fastmath settings."""
    deco = njit(cache=True, fastmath=FASTMATH, parallel=parallel)
    return deco if fn is None else deco(fn)
