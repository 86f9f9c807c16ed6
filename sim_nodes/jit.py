"""The one numba configuration every kernel uses.

``error_model='numpy'``: a float division by zero gives inf/nan instead of raising, which
removes a branch from every division and lets the lane loops vectorise.  No ``fastmath``:
the compiler may not reassociate or contract (FMA) floating-point operations, so a scalar
call and a vectorised batch compute bit-identical results.
"""
from numba import njit

OPTIONS = {'cache': True, 'error_model': 'numpy'}


def kernel(fn=None, **extra):
    """``@kernel`` / ``@kernel(inline='always', parallel=True)``: numba njit with OPTIONS."""
    if fn is None:
        return lambda f: njit(**OPTIONS, **extra)(f)
    return njit(**OPTIONS)(fn)
