"""The one numba configuration every kernel uses, and where its compiled code is cached.

``error_model='numpy'``: a float division by zero gives inf/nan instead of raising, which
removes a branch from every division and lets the lane loops vectorise.  No ``fastmath``:
the compiler may not reassociate or contract (FMA) floating-point operations, so a scalar
call and a vectorised batch compute bit-identical results.

Cache: numba keys a cached function by its own source file only, but our kernels inline
code from several files.  Unless ``NUMBA_CACHE_DIR`` is set, each kernel is therefore
cached in a folder named by a digest of every kernel source file of this environment
package and of the package that defines the kernel (files that use ``@kernel``), so an
edited model, selector or engine never runs stale machine code.  No package above this one
is named here: a package's kernels are found from the kernel's own source file.  numba
also keys each cache entry by its source file's path and modification time, so every
checkout (and every fresh clone) compiles once: ``make venv`` does it
(``sapga_ros.training.warm``).

Whatever compiles says so: the first compilation of a cached kernel in a process prints one
line on stderr (``COMPILING``), and ``compile_seconds()`` adds up the time spent compiling,
so that progress rates can leave it out.
"""
from __future__ import annotations

import hashlib
import os
import sys
import threading
import time
import weakref
from functools import lru_cache
from pathlib import Path

import numba.core.config
from numba import njit
from numba.core import event
from numba.core.caching import NullCache


def _wide_vectors() -> None:
    """Let the compiler use 512-bit vectors on a CPU with AVX-512 (LLVM prefers 256-bit ones
    there by default).  The lane loops compute the same bits at any vector width; the
    batch kernel runs about a fifth faster.  A NUMBA_CPU_NAME or NUMBA_CPU_FEATURES set by
    the user is left as it is, and NUMBA_ENABLE_AVX=0 turns AVX-512 off here too.  Set
    before any kernel is compiled: numba reads it when it makes its code generator."""
    if os.environ.get('NUMBA_CPU_FEATURES') or os.environ.get('NUMBA_CPU_NAME'):
        return
    from numba.core.codegen import get_host_cpu_features   # honours NUMBA_ENABLE_AVX
    features = get_host_cpu_features()
    if '+avx512f' in features.split(','):
        numba.core.config.CPU_FEATURES = features + ',-prefer-256-bit'


_wide_vectors()
_ENV_DIR = Path(__file__).resolve().parent
_USER_CACHE_DIR = os.environ.get('NUMBA_CACHE_DIR')
OPTIONS = {'cache': True, 'error_model': 'numpy'}
COMPILING = 'compiling kernels (first run of this checkout: a minute or so; cached after)...'


@lru_cache(maxsize=None)
def kernel_files(package_dir: Path) -> tuple[Path, ...]:
    """The source files under ``package_dir`` that define compiled kernels."""
    return tuple(p for p in sorted(package_dir.rglob('*.py'))
                 if '@kernel' in p.read_text(encoding='utf-8', errors='replace'))


def package_dir(source_file: str) -> Path:
    """The top-level package folder holding ``source_file``."""
    path = Path(source_file).resolve().parent
    while (path.parent / '__init__.py').is_file():
        path = path.parent
    return path


@lru_cache(maxsize=None)
def kernel_digest(package: Path = _ENV_DIR) -> str:
    """Digest of the kernel sources of this package and of ``package``."""
    h = hashlib.sha256()
    for directory in sorted({_ENV_DIR, package}):
        for path in (Path(__file__).resolve(), *kernel_files(directory)):
            h.update(str(path.relative_to(directory.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def cache_dir(source_file: str) -> str:
    """Where the kernel defined in ``source_file`` is cached."""
    if _USER_CACHE_DIR:
        return _USER_CACHE_DIR
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return os.path.join(base, 'sapga_ros', f'numba-{kernel_digest(package_dir(source_file))}')


class _CompileWatch(event.Listener):
    """Listens to numba's compile events (fired on a cache miss only): says once that our
    kernels compile, and adds up the wall time of the outermost compilations."""

    def __init__(self) -> None:
        self.kernels: weakref.WeakSet = weakref.WeakSet()
        self.seconds = 0.0
        self.said = False
        self._depth = threading.local()
        self._started = 0.0

    def on_start(self, ev: event.Event) -> None:
        depth = getattr(self._depth, 'n', 0)
        self._depth.n = depth + 1
        if depth:
            return
        self._started = time.perf_counter()
        dispatcher = ev.data['dispatcher']
        if not self.said and dispatcher in self.kernels \
                and not isinstance(dispatcher._cache, NullCache):
            self.said = True
            print(COMPILING, file=sys.stderr, flush=True)

    def on_end(self, ev: event.Event) -> None:
        self._depth.n -= 1
        if not self._depth.n:
            self.seconds += time.perf_counter() - self._started


_WATCH = _CompileWatch()
event.register('numba:compile', _WATCH)


def compile_seconds() -> float:
    """Seconds this process has spent compiling kernels so far (not loading them from the
    cache): a rate measured over an interval leaves out the growth of this."""
    return _WATCH.seconds


def _compile(fn, extra: dict):
    saved = numba.core.config.CACHE_DIR
    numba.core.config.CACHE_DIR = cache_dir(fn.__code__.co_filename)  # read at decoration
    try:
        dispatcher = njit(**{**OPTIONS, **extra})(fn)
    finally:
        numba.core.config.CACHE_DIR = saved
    _WATCH.kernels.add(dispatcher)
    return dispatcher


def kernel(fn=None, **extra):
    """``@kernel`` / ``@kernel(inline='always', parallel=True)``: numba njit with OPTIONS
    (``cache=False`` for functions made at run time: numba keys a closure's cache by its
    pickled cells, which differ in every process)."""
    if fn is None:
        return lambda f: _compile(f, extra)
    return _compile(fn, {})
