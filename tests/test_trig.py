"""Accuracy of the dynamics' own sin and cos (sim_nodes/models/trig.py): within 2 ulp of
libm (numpy) for the arguments a pendulum sees, |x| <= 1e5, including the hard ones next
to multiples of pi/2, and the same bits in a scalar call as in a vectorised loop."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from sim_nodes.models import trig

LIMIT = 1e5  # [rad] the largest argument the trig module promises accuracy for


@njit(cache=True)
def sincos_all(x):
    """trig.sincos over an array, in one compiled (vectorisable) loop."""
    s = np.empty_like(x)
    c = np.empty_like(x)
    for i in range(x.shape[0]):
        s[i], c[i] = trig.sincos(x[i])
    return s, c


def ulp_errors(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Errors of trig's sin and cos against numpy's, in units of numpy's result's ulp."""
    s, c = sincos_all(x)
    ref_s, ref_c = np.sin(x), np.cos(x)
    return (np.abs(s - ref_s) / np.spacing(np.abs(ref_s)),
            np.abs(c - ref_c) / np.spacing(np.abs(ref_c)))


def assert_within_2_ulp(x: np.ndarray) -> None:
    err_s, err_c = ulp_errors(x)
    worst_s, worst_c = int(np.argmax(err_s)), int(np.argmax(err_c))
    assert err_s[worst_s] <= 2.0, f'sin({x[worst_s]!r}) is {err_s[worst_s]} ulp off'
    assert err_c[worst_c] <= 2.0, f'cos({x[worst_c]!r}) is {err_c[worst_c]} ulp off'


def test_sincos_within_2_ulp_over_the_whole_range(rng):
    """For a million arguments uniform in [-1e5, 1e5] sin and cos are within 2 ulp."""
    assert_within_2_ulp(rng.uniform(-LIMIT, LIMIT, 1_000_000))


def test_sincos_within_2_ulp_for_pendulum_angles(rng):
    """For the arguments of the models (wrapped angles and their sums, [-4pi, 4pi]) sin and
    cos are within 2 ulp."""
    assert_within_2_ulp(rng.uniform(-4 * math.pi, 4 * math.pi, 1_000_000))


def test_sincos_within_2_ulp_next_to_multiples_of_half_pi(rng):
    """At every double nearest k pi/2 for |k pi/2| <= 1e5, at its neighbours one ulp away,
    and at small offsets from it, where the argument reduction cancels most bits, sin and
    cos are within 2 ulp (relative to the tiny result, not to 1)."""
    kmax = int(LIMIT / (math.pi / 2))
    x = np.arange(-kmax, kmax + 1) * (math.pi / 2)
    assert_within_2_ulp(x)
    assert_within_2_ulp(np.nextafter(x, np.inf))
    assert_within_2_ulp(np.nextafter(x, -np.inf))
    for offset in (1e-14, 1e-12, 1e-9, 1e-6, 1e-3):
        assert_within_2_ulp(x + rng.uniform(-offset, offset, x.size))


@pytest.mark.parametrize('x', [0.0, -0.0, 5e-324, 1e-300, 1e-9, -1e-9, math.pi / 4,
                               -math.pi / 4, math.pi, 2 * math.pi, LIMIT, -LIMIT])
def test_sincos_within_2_ulp_at_special_arguments(x):
    """At zero, tiny, pi/4 (the reduction's edge), pi, 2pi and +-1e5, sin and cos are within
    2 ulp, and sin(0) == 0, cos(0) == 1 exactly."""
    assert_within_2_ulp(np.array([x]))
    if x == 0.0:
        assert trig.sin(x) == 0.0 and trig.cos(x) == 1.0


def test_pythagorean_identity_holds_to_rounding(rng):
    """sin^2 + cos^2 = 1 within a few ulp of 1 over the whole range."""
    s, c = sincos_all(rng.uniform(-LIMIT, LIMIT, 200_000))
    assert np.max(np.abs(s * s + c * c - 1.0)) < 4 * np.finfo(float).eps


def test_scalar_calls_give_the_bits_of_the_vectorised_loop(rng):
    """trig.sin / trig.cos called one argument at a time return exactly (==) what the
    compiled loop over many arguments returns: the same bits in the ROS node's scalar
    step and in the batch evaluator."""
    x = np.concatenate([rng.uniform(-LIMIT, LIMIT, 300), rng.uniform(-10, 10, 300)])
    s, c = sincos_all(x)
    assert [trig.sin(v) for v in x] == list(s)
    assert [trig.cos(v) for v in x] == list(c)
