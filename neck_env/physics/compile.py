"""How the physics is compiled: one numba configuration for every hot function.

``fastmath`` allows contraction (FMA), reassociation, reciprocal approximation, ignoring the sign
of zero and approximate libm functions -- but not "no NaN / no inf": budgets and supply limits
use ``inf`` as "none", and NaNs must propagate to the checks that reject them.
"""

from numba import njit

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


def jit(fn=None, *, parallel: bool = False):
    """``numba.njit`` with the project's cache and fastmath settings."""
    deco = njit(cache=True, fastmath=FASTMATH, parallel=parallel)
    return deco if fn is None else deco(fn)
