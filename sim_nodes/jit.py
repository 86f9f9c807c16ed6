"""The one numba configuration every kernel uses, and where its compiled code is cached.

``error_model='numpy'``: a float division by zero gives inf/nan instead of raising, which
removes a branch from every division and lets the lane loops vectorise.  No ``fastmath``:
the compiler may not reassociate or contract (FMA) floating-point operations, so a scalar
call and a vectorised batch compute bit-identical results.

Cache: numba keys a cached function by its own source file only, but our kernels inline
code from several files.  Unless ``NUMBA_CACHE_DIR`` is set, the cache therefore lives in a
folder named by a digest of every kernel source file, so an edited model never runs stale
machine code.
"""
import hashlib
import os
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
KERNEL_SOURCES = ('sim_nodes/jit.py', 'sim_nodes/goal.py', 'sim_nodes/models/*.py',
                  'sapga_ros/selector.py', 'sapga_ros/kernels.py', 'sapga_ros/qlearning.py')


def kernel_digest() -> str:
    """Digest of the source files the compiled kernels are made from."""
    h = hashlib.sha256()
    for pattern in KERNEL_SOURCES:
        for path in sorted(_ROOT.glob(pattern)):
            h.update(path.name.encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _default_cache_dir() -> str:
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'sapga_ros', f'numba-{kernel_digest()}')


if not os.environ.get('NUMBA_CACHE_DIR'):
    os.environ['NUMBA_CACHE_DIR'] = _default_cache_dir()
    import numba.core.config
    numba.core.config.reload_config()

from numba import njit  # noqa: E402 - after the cache folder is chosen

OPTIONS = {'cache': True, 'error_model': 'numpy'}


def kernel(fn=None, **extra):
    """``@kernel`` / ``@kernel(inline='always', parallel=True)``: numba njit with OPTIONS."""
    if fn is None:
        return lambda f: njit(**OPTIONS, **extra)(f)
    return njit(**OPTIONS)(fn)
