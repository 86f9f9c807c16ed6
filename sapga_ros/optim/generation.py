"""A SAP-GA generation's operators in compiled passes, bit for bit and draw for draw the
operators of ``sapga_ros.optim.operators`` applied family by family.

``unions``: each family's deduplicated union of its two parents (first-seen order), from
exemplar records compared bit for bit (as ``parents_union``).  ``children``: every child of
every family by uniform exemplar crossover (as ``uniform_crossover``); a child that needs
repairing is handed back to the caller, which repairs it (``operators.repair``) and
resumes.  ``refresh_draws``: the refresh operator's draws for every family's best member
(as ``refresh``).  The passes draw from the run's generator itself: the crossovers step
its PCG64 state inline (``sapga_ros.optim.pcg``), the refresh pass through numba's
Generator; both draw NumPy's sequence from the same bit generator (tests/test_generation.py
checks the children, the clones and the generator's state against the operators one by one).
``crossover_group`` hands the children back as one flat group (``FlatPolicies``).
"""
from __future__ import annotations

import numpy as np

from sapga_ros.optim.operators import repair
from sapga_ros.optim.pcg import pcg_double, set_state, state_of
from sapga_ros.policies.batch import FlatPolicies, flat_of
from sapga_ros.policies.exemplar import ExemplarPolicy, concat_policies
from sapga_ros.policies.styles import STYLES
from sim_nodes.jit import kernel

DONE, REPAIR = 0, 1                # how a ``children`` pass ended


@kernel
def unions(keys, fam_start, uid, urep, ucount):
    """Family f holds rows fam_start[f]..fam_start[f+1]-1 of ``keys`` (one row of int64
    words per exemplar record).  uid[i]: the index of row i's record in its family's union
    (first-seen order); urep[fam_start[f] + u]: the row of union member u; ucount[f]: the
    union's size."""
    for f in range(fam_start.shape[0] - 1):
        a, b = fam_start[f], fam_start[f + 1]
        n = b - a
        h = np.empty(n, dtype=np.uint64)
        for i in range(n):
            x = np.uint64(1469598103934665603)
            for w in range(keys.shape[1]):
                x = (x ^ np.uint64(keys[a + i, w])) * np.uint64(1099511628211)
                x ^= x >> np.uint64(29)
            h[i] = x
        order = np.argsort(h, kind='mergesort')        # equal hashes: rows in order
        rep = np.arange(n)
        q = 0
        while q < n:
            e = q + 1
            while e < n and h[order[e]] == h[order[q]]:
                e += 1
            for s in range(q + 1, e):                  # the first equal row represents
                i = order[s]
                for t in range(q, s):
                    j = order[t]
                    if rep[j] == j and _same(keys, a + i, a + j):
                        rep[i] = j
                        break
            q = e
        count = 0
        for i in range(n):
            if rep[i] == i:
                uid[a + i] = count
                urep[a + count] = a + i
                count += 1
            else:
                uid[a + i] = uid[a + rep[i]]
        ucount[f] = count


@kernel(inline='always')
def _same(keys, i, j):
    for w in range(keys.shape[1]):
        if keys[i, w] != keys[j, w]:
            return False
    return True


@kernel(inline='always')
def _take(st, uid, urep, mark, stamp, a, first, m, p, out_idx, write, count):
    """One draw per exemplar first..first+m-1 of the family at ``a``: taken with probability
    ``p`` unless its record is taken already (``mark``); the new ones appended to
    out_idx[write + count:]; returns count.  Without branches on the draws (taken half the
    time, at random, they were mispredicted): the row is always written, kept by count."""
    for i in range(first, first + m):
        j = uid[a + i]
        new = (pcg_double(st) < p) & (mark[j] != stamp)
        mark[j] = stamp if new else mark[j]
        out_idx[write + count] = urep[a + j]
        count += np.int64(new)
    return count


@kernel
def children(st, uid, urep, fam_start, n1, ucount, f, c, n_child, low, span, l_min, l_max,
             max_tries, out_idx, out_start):
    """Children (f, c) onwards (family-major) until done or a child to repair, drawing
    from the PCG64 state ``st`` (``pcg_double``).  Child
    k = f n_child + c is the rows out_idx[out_start[k]:out_start[k + 1]]; a child to
    repair is left empty; an attempt may write up to a union's size past its start
    (``out_idx`` has that room after the last child).  Each attempt draws what
    ``uniform_crossover``'s does: the rate, then one double per exemplar of parent 1, then
    of parent 2.  Returns (f, c, DONE or REPAIR: child (f, c), its attempts drawn)."""
    mark = np.full(max(1, np.max(ucount)), -1)
    stamp = 0
    families = fam_start.shape[0] - 1
    while f < families:
        a = fam_start[f]
        m1 = n1[f]
        m2 = fam_start[f + 1] - a - m1
        while c < n_child:
            k = f * n_child + c
            write = out_start[k]
            legal = False
            for _ in range(max_tries):
                r = low + span * pcg_double(st)        # as Generator.uniform(low, high)
                stamp += 1
                count = _take(st, uid, urep, mark, stamp, a, 0, m1, r, out_idx, write, 0)
                count = _take(st, uid, urep, mark, stamp, a, m1, m2, 1.0 - r, out_idx, write,
                              count)                   # E^p1 with probability r, E^p2 1 - r
                if l_min <= count <= l_max:
                    legal = True
                    break
            if not legal:
                out_start[k + 1] = write
                return f, c, REPAIR
            out_start[k + 1] = write + count
            c += 1
        c = 0
        f += 1
    return f, c, DONE


def record_keys(states, states2, actions, values, style: str) -> np.ndarray:
    """(L, W) int64: the bits of each exemplar's record, every field ``style`` uses (equal
    records, equal rows; as ``ExemplarPolicy.records``)."""
    spec = STYLES[style]
    cols = [states.view(np.int64)]
    if spec.uses('state2'):
        cols.append(states2.view(np.int64))
    if spec.uses('action'):
        cols.append(actions.astype(np.float64)[:, None].view(np.int64))
    if spec.uses('value'):
        cols.append(values[:, None].view(np.int64))
    return np.ascontiguousarray(np.concatenate(cols, axis=1))


def crossover_group(parents: list[tuple[ExemplarPolicy, ExemplarPolicy]],
                    rng: np.random.Generator, n_child: int, l_min: int, l_max: int,
                    rate: tuple[float, float], max_tries: int) -> tuple[FlatPolicies, int]:
    """The ``n_child`` children of each pair of ``parents`` (family by family) as one flat
    group (family-major), drawn from ``rng`` exactly as ``uniform_crossover`` would draw
    them one by one, and the number of children repaired."""
    first = parents[0][0]
    problem, style = first.problem, first.style
    flat = [p for pair in parents for p in pair]
    states = np.concatenate([p.states for p in flat])
    states2 = np.concatenate([p.states2 for p in flat])
    actions = np.concatenate([p.actions for p in flat])
    values = np.concatenate([p.values for p in flat])
    sizes = np.array([len(p) for p in flat], dtype=np.int64)
    fam_start = np.zeros(len(parents) + 1, dtype=np.int64)
    fam_start[1:] = np.cumsum(sizes.reshape(-1, 2).sum(axis=1))
    n1 = np.ascontiguousarray(sizes[0::2])
    total = int(fam_start[-1])
    uid = np.empty(total, dtype=np.int64)
    urep = np.empty(total, dtype=np.int64)
    ucount = np.empty(len(parents), dtype=np.int64)
    unions(record_keys(states, states2, actions, values, style), fam_start, uid, urep, ucount)
    kids = len(parents) * n_child
    widest = int(np.max(np.diff(fam_start)))
    out_idx = np.empty(kids * l_max + widest, dtype=np.int64)
    out_start = np.zeros(kids + 1, dtype=np.int64)
    low, span = float(rate[0]), float(rate[1]) - float(rate[0])   # as Generator.uniform
    repaired: dict[int, ExemplarPolicy] = {}
    f = c = 0
    words = state_of(rng)
    while f < len(parents):
        f, c, status = children(words, uid, urep, fam_start, n1, ucount, f, c, n_child, low,
                                span, l_min, l_max, max_tries, out_idx, out_start)
        set_state(rng, words)
        if status == DONE:
            break
        a = fam_start[f]
        union = _subset(problem, style, states, states2, actions, values,
                        urep[a:a + ucount[f]])
        repaired[f * n_child + c] = repair(union, l_min, l_max, rng)
        words = state_of(rng)
        c += 1
        if c == n_child:
            f, c = f + 1, 0
    lengths = np.diff(out_start)
    rows = out_idx[:out_start[-1]]
    if repaired:           # a repaired child's records appended, its rows in its place
        parts = [repaired[k] for k in sorted(repaired)]
        pieces, at, end = [], 0, total
        for k, part in zip(sorted(repaired), parts):
            lengths[k] = len(part)
            pieces += [rows[at:out_start[k]], np.arange(end, end + len(part))]
            at, end = out_start[k], end + len(part)
        rows = np.concatenate(pieces + [rows[at:]])
        states, actions, values, states2 = (
            np.concatenate([source] + [getattr(part, name) for part in parts])
            for source, name in ((states, 'states'), (actions, 'actions'),
                                 (values, 'values'), (states2, 'states2')))
    return FlatPolicies(problem, style, states, actions, values, states2, lengths,
                        np.ascontiguousarray(rows)), len(repaired)


def _subset(problem, style, states, states2, actions, values, rows) -> ExemplarPolicy:
    return ExemplarPolicy.of_valid(problem, states[rows], actions[rows], style, values[rows],
                                   states2[rows])


def compact(policy: ExemplarPolicy) -> ExemplarPolicy:
    """``policy`` with arrays of its own (a child's are views into its generation's)."""
    if policy.states.base is None:
        return policy
    return concat_policies([policy])


@kernel
def refresh_draws(rng, lengths, used, low, high, lo, hi, n_actions, value_low, value_high,
                  uses, redraw, counts, fresh_states, fresh_states2, fresh_actions,
                  fresh_values):
    """``refresh``'s draws for policy after policy (``lengths``; ``used`` their marks,
    concatenated), from ``rng`` itself (numba's Generator draws NumPy's sequence): the rate
    U(lo, hi), one double per exemplar, then, if any exemplar is re-drawn, the fresh
    records as ``random_exemplars`` draws them (states, second states, actions, values;
    ``uses``: the style's fields state2, action, value).  ``redraw`` marks, per policy
    ``counts``, fresh records in order (angles not yet wrapped)."""
    span = high - low
    a = 0
    w = 0
    for f in range(lengths.shape[0]):
        r = rng.uniform(lo, hi)
        count = 0
        for i in range(lengths[f]):
            hit = rng.random() < r
            redraw[a + i] = hit and not used[a + i]
            count += redraw[a + i]
        counts[f] = count
        if count:
            for i in range(count):
                for j in range(low.shape[0]):
                    fresh_states[w + i, j] = low[j] + span[j] * rng.random()
            if uses[0]:
                for i in range(count):
                    for j in range(low.shape[0]):
                        fresh_states2[w + i, j] = low[j] + span[j] * rng.random()
            if uses[1]:
                fresh_actions[w:w + count] = rng.integers(0, n_actions, size=count)
            if uses[2]:
                for i in range(count):
                    fresh_values[w + i] = rng.uniform(value_low, value_high)
            w += count
        a += lengths[f]


def refreshes(stars: list, rng: np.random.Generator,
              rate: tuple[float, float]) -> list[tuple[ExemplarPolicy, int]]:
    """``refresh(star.policy, star.used, rng, rate)`` of each star in turn, in one compiled
    pass of draws: the same clones, the same draws."""
    first = stars[0].policy
    problem, style = first.problem, first.style
    spec = STYLES[style]
    lengths = np.array([len(s.policy) for s in stars], dtype=np.int64)
    used = np.concatenate([s.used for s in stars])
    total = len(used)
    redraw = np.zeros(total, dtype=np.bool_)
    counts = np.zeros(len(stars), dtype=np.int64)
    dim = problem.dim
    fresh_states = np.empty((total, dim))
    fresh_states2 = np.empty((total, dim))
    fresh_actions = np.zeros(total, dtype=np.int64)
    fresh_values = np.zeros(total)
    uses = np.array([spec.uses('state2'), spec.uses('action'), spec.uses('value')])
    value_low, value_high = (float(x) for x in problem.return_range)
    refresh_draws(rng, lengths, used, np.asarray(problem.low, dtype=np.float64),
                  np.asarray(problem.high, dtype=np.float64), float(rate[0]), float(rate[1]),
                  len(problem.actions), value_low, value_high, uses, redraw, counts,
                  fresh_states, fresh_states2, fresh_actions, fresh_values)
    drawn = int(counts.sum())
    clones = flat_of([s.policy for s in stars])          # copies, in star order
    if drawn:                  # the fresh records, in order, into the exemplars re-drawn
        clones.states[redraw] = first._wrapped(fresh_states[:drawn])
        if uses[0]:
            clones.states2[redraw] = first._wrapped(fresh_states2[:drawn])
        clones.actions[redraw] = fresh_actions[:drawn]
        clones.values[redraw] = fresh_values[:drawn]
    return [(clones.policy(k), count) for k, count in enumerate(counts.tolist())]
