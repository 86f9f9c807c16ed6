"""NumPy's default bit generator (PCG64) stepped inside compiled passes.

numba's ``Generator.random()`` calls the bit generator through a function pointer, about
4 ns a draw; a SAP-GA generation's crossovers draw hundreds of thousands of doubles.
``pcg_double`` is PCG64's step (128-bit LCG, XSL-RR output) and NumPy's ``next_double`` on a
state held as four uint64 words, inlined: the same doubles in the same order
(tests/test_generation.py checks a million draws and the state after them against NumPy).
``state_of`` and ``set_state`` move the state between a ``Generator`` and the words.
"""
from __future__ import annotations

import numpy as np

from sapga_ros.errors import SapgaError
from sim_nodes.jit import kernel

_WORD = (1 << 64) - 1
_MUL_HI = np.uint64(2549297995355413924)      # PCG64's 128-bit multiplier, high word
_MUL_LO = np.uint64(4865540595714422341)      # and low word
_LOW32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)


@kernel(inline='always')
def _mulhi(a, b):
    """The high word of the 128-bit product of two uint64."""
    a0, a1 = a & _LOW32, a >> _S32
    b0, b1 = b & _LOW32, b >> _S32
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> _S32) + (p01 & _LOW32) + (p10 & _LOW32)
    return p11 + (p01 >> _S32) + (p10 >> _S32) + (mid >> _S32)


@kernel(inline='always')
def pcg_double(st):
    """The next double in [0, 1) of the PCG64 state st = [state hi, state lo, inc hi, inc
    lo] (updated), as ``Generator.random()``."""
    shi, slo = st[0], st[1]
    lo = slo * _MUL_LO
    hi = _mulhi(slo, _MUL_LO) + slo * _MUL_HI + shi * _MUL_LO
    new_lo = lo + st[3]
    hi = hi + st[2] + (np.uint64(1) if new_lo < lo else np.uint64(0))
    st[0] = hi
    st[1] = new_lo
    x = hi ^ new_lo
    rot = hi >> np.uint64(58)
    out = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return np.float64(out >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@kernel
def pcg_doubles(st, out):
    """Fill ``out`` with draws of ``pcg_double`` (a check against NumPy)."""
    for i in range(out.shape[0]):
        out[i] = pcg_double(st)


def state_of(rng: np.random.Generator) -> np.ndarray:
    """The generator's PCG64 state as the four words ``pcg_double`` steps."""
    s = rng.bit_generator.state
    if s.get('bit_generator') != 'PCG64':
        raise SapgaError(f'compiled draws need a PCG64 generator, not {s.get("bit_generator")}')
    state, inc = s['state']['state'], s['state']['inc']
    return np.array([state >> 64, state & _WORD, inc >> 64, inc & _WORD], dtype=np.uint64)


def set_state(rng: np.random.Generator, words: np.ndarray) -> None:
    """Put the words' state back into the generator (its buffered 32 bits kept)."""
    s = rng.bit_generator.state
    s['state']['state'] = (int(words[0]) << 64) | int(words[1])
    rng.bit_generator.state = s
