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


FEATURES = """
import sapga_ros.bench.batch  # imports the straightforward kernel's plain njit functions too
import llvmlite.binding as llvm
from numba.core.registry import cpu_target
host = llvm.get_host_cpu_features().flatten().split(',')
used = cpu_target.target_context.codegen()._tm_features.split(',')
print('+avx512f' in host, '-prefer-256-bit' in used)
"""


def test_the_code_generator_uses_wide_vectors_on_avx512_unless_the_user_says_otherwise():
    """On an AVX-512 CPU every kernel of the process (the straightforward yardstick's
    too) is compiled with 512-bit vectors preferred; a NUMBA_CPU_FEATURES of the user's is
    left alone, and NUMBA_ENABLE_AVX=0 keeps AVX (and so the wide vectors) off."""
    user = ('NUMBA_CPU_FEATURES', 'NUMBA_CPU_NAME')
    env = {k: v for k, v in os.environ.items() if k not in user}
    env['PYTHONPATH'] = os.pathsep.join([str(ROOT), os.environ.get('PYTHONPATH', '')])
    out = subprocess.run([sys.executable, '-c', FEATURES], capture_output=True, text=True,
                         env=env, timeout=300, check=True).stdout.split()
    assert out[0] == out[1], out              # wide exactly where the CPU has AVX-512
    host = subprocess.run([sys.executable, '-c', 'import llvmlite.binding as b; '
                           'print(b.get_host_cpu_features().flatten())'], capture_output=True,
                          text=True, env=env, timeout=300, check=True).stdout.strip()
    for name, value in (('NUMBA_CPU_FEATURES', host), ('NUMBA_ENABLE_AVX', '0')):
        out = subprocess.run([sys.executable, '-c', FEATURES], capture_output=True, text=True,
                             env={**env, name: value}, timeout=300, check=True).stdout.split()
        assert out[1] == 'False', (name, out)
