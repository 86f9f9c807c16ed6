"""numba's cache as ``sim_nodes/jit.py`` sets it up: whatever compiles says so in one line on
stderr, a warm cache compiles nothing and says nothing, compile time is counted (for rates
that leave it out)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from sim_nodes.jit import COMPILING

ROOT = Path(__file__).resolve().parents[1]

KERNEL = """
from sim_nodes.jit import compile_seconds, kernel


@kernel
def twice(x):
    return 2.0 * x


@kernel(cache=False)
def thrice(x):
    return 3.0 * x


print(twice(1.5), thrice(1.0), compile_seconds() > 0)
"""


def run_kernel(tmp_path: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path / 'cache'),
           'PYTHONPATH': os.pathsep.join([str(ROOT), os.environ.get('PYTHONPATH', '')])}
    return subprocess.run([sys.executable, str(tmp_path / 'k.py')], capture_output=True,
                          text=True, env=env, timeout=300)


def test_a_cold_cache_says_it_compiles_and_a_warm_one_is_silent(tmp_path):
    """First process: one line on stderr and compile time counted; second process (same
    file, same cache): the cached kernel loads, nothing said; the uncached kernel (made at
    run time) compiles again, counted but not announced."""
    (tmp_path / 'k.py').write_text(KERNEL)
    cold = run_kernel(tmp_path)
    assert cold.returncode == 0, cold.stderr
    assert cold.stdout.split() == ['3.0', '3.0', 'True']
    assert cold.stderr.splitlines() == [COMPILING]
    warm = run_kernel(tmp_path)
    assert warm.returncode == 0, warm.stderr
    assert warm.stdout.split() == ['3.0', '3.0', 'True'] and warm.stderr == ''
