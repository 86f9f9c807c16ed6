"""Nearest-neighbour action selector of the state-action style (paper section 3).

Distance: normalised Euclidean.  Each coordinate is divided by its range (2pi for angles,
8pi / 18pi for the acrobot's velocities, 5 for x, 32 for v, 8pi for the PDIP's
theta_dot), so an angle becomes a fraction of a turn in [0, 1) and its difference is taken
the short way round the circle.  Ties go to the lowest index (strict ``<``).

Exemplar states are stored normalised and dimension-major, ``(D, L)``, so the distance loop
runs over exemplars innermost and vectorises.  The same compiled ``nearest`` serves the
batch evaluator and the ROS policy node, which is what makes a lockstep ROS episode equal
an offline evaluation bit for bit.
"""
import math

import numpy as np
from sim_nodes.jit import kernel


@kernel(inline='always')
def normalize_into(s, inv_range, is_angle, out):
    """out = s / range, angles wrapped to a fraction of a turn in [0, 1)."""
    for d in range(s.shape[0]):
        u = s[d] * inv_range[d]
        if is_angle[d]:
            u = u - math.floor(u)
            if u >= 1.0:
                u = 0.0
        out[d] = u


@kernel(inline='always')
def normalize_lanes(S, n, inv_range, is_angle, out):
    """out[k] = ``normalize_into`` of column k of S (D, W), for k < n, the columns side by
    side (the same arithmetic per coordinate)."""
    for d in range(S.shape[0]):
        inv = inv_range[d]
        row = S[d]
        if is_angle[d]:
            for k in range(n):
                u = row[k] * inv
                u = u - math.floor(u)
                out[k, d] = 0.0 if u >= 1.0 else u
        else:
            for k in range(n):
                out[k, d] = row[k] * inv


@kernel(inline='always')
def circular(diff):
    """The difference ``diff`` of two fractions of a turn in [0, 1), taken the short way
    round: diff - rint(diff), whose magnitude is min(|diff|, 1 - |diff|) exactly (for
    |diff| <= 1/2 it is diff; above, diff -+ 1 and 1 - |diff| are both exact by Sterbenz's
    lemma, |diff| being in [1/2, 1)), so its square is that of the min bit for bit.  rint
    rounds halves to even: |diff| = 1/2 stays 1/2 either way."""
    return diff - np.rint(diff)


@kernel(inline='always')
def sq_distances(u, ex, n, is_angle, acc):
    """acc[j] = squared normalised distance from u to exemplar j of ex[:, :n].

    The sum runs over the coordinates in order; the first coordinate's square is stored
    rather than added to 0.0 (the same value: squares are +0, positive or NaN), which saves
    a pass over acc.

    An angle's difference the short way round is ``circular``'s, one operation fewer than
    ``min(|diff|, 1 - |diff|)`` (``sq_distance``) and the same square bit for bit."""
    if u.shape[0] == 0:
        for j in range(n):
            acc[j] = 0.0
    for d in range(u.shape[0]):
        ud = u[d]
        row = ex[d]
        if is_angle[d]:
            if d == 0:
                for j in range(n):
                    diff = circular(ud - row[j])
                    acc[j] = diff * diff
            else:
                for j in range(n):
                    diff = circular(ud - row[j])
                    acc[j] += diff * diff
        elif d == 0:
            for j in range(n):
                diff = ud - row[j]
                acc[j] = diff * diff
        else:
            for j in range(n):
                diff = ud - row[j]
                acc[j] += diff * diff


@kernel
def sq_distance(u, v, is_angle):
    """Squared normalised distance between two normalised states."""
    total = 0.0
    for d in range(u.shape[0]):
        diff = u[d] - v[d]
        if is_angle[d]:
            diff = math.fabs(diff)
            diff = min(diff, 1.0 - diff)
        total += diff * diff
    return total


@kernel(inline='always')
def argmin(acc, n):
    """The lowest index of the smallest of the squared distances acc[:n] (n >= 1): what a
    scan keeping the first strict minimum returns (NaN never smaller; acc[0] NaN: 0).

    Squared distances are +0, positive, inf or NaN, and such doubles order as their bit
    patterns do as unsigned integers, NaN (of either sign) above inf.  So the smallest is
    an unsigned integer minimum, and its first index an integer minimum: two passes
    without branches that the compiler vectorises (a float minimum it may not reorder).
    """
    if not acc[0] == acc[0]:
        return 0
    bits = acc[:n].view(np.uint64)
    low = bits[0]
    for j in range(n):
        low = min(low, bits[j])
    first = n
    for j in range(n):
        first = min(first, j if bits[j] == low else n)
    return first


@kernel(inline='always')
def nearest(u, ex, n, is_angle, acc):
    """Index of the exemplar nearest to the normalised state u among ex[:, :n].

    ``acc`` is scratch of length >= n (squared distances).  Ties: the lowest index.
    """
    sq_distances(u, ex, n, is_angle, acc)
    return argmin(acc, n)


@kernel
def normalize_rows_into(states, inv_range, is_angle, out):
    """out[:, j] = ``normalize_into`` of states[j] for every row (one compiled call)."""
    for j in range(states.shape[0]):
        normalize_into(states[j], inv_range, is_angle, out[:, j])


@kernel
def normalize_padded_into(states, lengths, inv_range, is_angle, out):
    """Policies' exemplar rows side by side (``lengths[k]`` rows each) -> out[k, :, j] =
    ``normalize_into`` of policy k's row j (a padded batch, in one compiled call)."""
    start = 0
    for k in range(lengths.shape[0]):
        for j in range(lengths[k]):
            normalize_into(states[start + j], inv_range, is_angle, out[k, :, j])
        start += lengths[k]


@kernel
def normalize_rows_padded_into(states, rows, lengths, inv_range, is_angle, out):
    """``normalize_padded_into`` of states[rows] (policy k: the next lengths[k] rows)."""
    start = 0
    for k in range(lengths.shape[0]):
        for j in range(lengths[k]):
            normalize_into(states[rows[start + j]], inv_range, is_angle, out[k, :, j])
        start += lengths[k]


@kernel
def pad_rows_into(flat, rows, lengths, out):
    """``pad_into`` of flat[rows]."""
    start = 0
    for k in range(lengths.shape[0]):
        for j in range(lengths[k]):
            out[k, j] = flat[rows[start + j]]
        start += lengths[k]


@kernel
def pad_into(flat, lengths, out):
    """Policies' per-exemplar values side by side -> out[k, j] = policy k's value j."""
    start = 0
    for k in range(lengths.shape[0]):
        for j in range(lengths[k]):
            out[k, j] = flat[start + j]
        start += lengths[k]


def normalize_states(states: np.ndarray, ranges: np.ndarray, is_angle: np.ndarray,
                     out: np.ndarray | None = None) -> np.ndarray:
    """(L, D) raw exemplar states -> (D, L) normalised, as ``nearest`` takes them (into
    ``out`` if given, e.g. a slice of a packed batch)."""
    states = np.ascontiguousarray(states, dtype=np.float64)
    if out is None:
        out = np.empty((states.shape[1], states.shape[0]), dtype=np.float64)
    normalize_rows_into(states, 1.0 / ranges, is_angle, out)
    return out


def distances(state, states, ranges, is_angle) -> np.ndarray:
    """Normalised distances from one raw state to each raw exemplar state (for people)."""
    u = np.empty(len(ranges))
    normalize_into(np.asarray(state, dtype=np.float64), 1.0 / ranges, is_angle, u)
    ex = normalize_states(np.asarray(states, dtype=np.float64), ranges, is_angle)
    diff = np.abs(ex - u[:, None])
    diff[is_angle] = np.minimum(diff[is_angle], 1.0 - diff[is_angle])
    return np.sqrt((diff ** 2).sum(axis=0))
