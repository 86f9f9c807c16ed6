"""``summary.json`` and ``experiment.json`` of an experiment directory, read back as hostile
input by ``sapga experiment report``: every field the report uses is checked (types,
shapes, lengths, finiteness, bounds) and a file that fails is one ``DataFileError`` line
naming the file and the field.  Numbers written as null (nan, no data) read as None where
the report shows them, so they print as ``n/a``.  Every number the report prints or draws
is bounded to what a figure can hold: values (returns, of order 1e4 in real runs) and delta*
(below 10 in real runs) within the bounds of the run files (``run_files.bounds``);
the measures that come as a set (the returned policies', the hold task's) are all there
or all absent.
"""
from __future__ import annotations

import math
import os
from typing import Any

from sapga_ros.errors import DataFileError
from sapga_ros.io import schema
from sapga_ros.io.jsonfile import read_json
from sapga_ros.policies.controller_row import MAX_DELAY
from sapga_ros.training.experiment_set import MAX_SEEDS, MAX_STEPS, METHODS
from sapga_ros.training.run_files import MAX_COUNT, bounds, configured_problem
from sim_nodes.params import DELTA, MAX_EPISODES

MAX_SUMMARY_BYTES = 16 << 20
MAX_INFO_BYTES = 1 << 20
MAX_EXPERIMENTS = 10_000
MAX_GRID = 10_000
WORD = r'[A-Za-z0-9][A-Za-z0-9_-]{0,39}'


def _optional(x: float) -> float | None:
    return None if math.isnan(x) else x


def _ci(value: Any, where: str, low: float, high: float) -> list[float] | None:
    """An interval [a, b] (a <= b) within [low, high]; None for null."""
    if value is None:
        return None
    ci = schema.numbers(value, where, 2, length=2, low=low, high=high)
    if ci[0] > ci[1]:
        raise DataFileError(f'{where}: expected [low, high] with low <= high, got {ci}')
    return ci


def _parts(key: str) -> tuple[tuple[str, float, float], ...]:
    """(part, low, high) of the mean and the standard deviation of measure ``key``."""
    low, high = bounds(key)
    return ('mean', low, high), ('std', 0.0, high - max(low, 0.0))


def _measure(f: dict, key: str, where: str) -> dict:
    """Mean, std (None for null) and 95 % interval of measure ``key`` of a final."""
    out = {}
    for part, low, high in _parts(key):
        name = f'{key}_{part}'
        out[name] = _optional(schema.number(schema.field(f, name, where), f'{where}.{name}',
                                            low, high, null=True))
    out[f'{key}_ci95'] = _ci(f.get(f'{key}_ci95'), f'{where}.{key}_ci95', *bounds(key))
    return out


def _count(f: dict, key: str, where: str, runs: int) -> int:
    return schema.integer(schema.field(f, key, where), f'{where}.{key}', 0, runs)


def _final(doc: Any, where: str, runs_max: int) -> dict:
    """The final measures; the returned policies' and the hold task's come as whole sets
    (one field of a set present: every field of it required)."""
    f = schema.mapping(doc, where)
    runs = _count(f, 'runs', where, runs_max)
    out: dict[str, Any] = {'achieved': _count(f, 'achieved', where, runs), 'runs': runs}
    for key in ('best_value', 'delta_star'):
        out.update(_measure(f, key, where))
    for key in ('delta_star_alt', 'greedy_delta_star'):
        if f'{key}_mean' in f:
            out.update(_measure(f, key, where))
    if 'delta_star_alt_mean' in out:
        out['achieved_alt'] = _count(f, 'achieved_alt', where, runs)
    returned = ('policy_value_mean', 'policy_delta_star_mean', 'policy_reached')
    if any(key in f for key in returned):           # the returned policies' own episodes
        for key in ('policy_value', 'policy_delta_star'):
            out.update(_measure(f, key, where))
        for key in ('policy_reached', 'policy_rail_runs'):
            out[key] = _count(f, key, where, runs)
        out['policy_rail_contacts_mean'] = schema.number(
            schema.field(f, 'policy_rail_contacts_mean', where),
            f'{where}.policy_rail_contacts_mean', 0, MAX_COUNT)
    for key in ('achieved', 'achieved_alt', 'policy_reached'):
        if key in out and f.get(f'{key}_ci95') is not None:   # Wilson intervals
            out[f'{key}_ci95'] = _ci(f[f'{key}_ci95'], f'{where}.{key}_ci95', 0, 1)
    if any(key in f for key in ('holding', 'hold_fraction_mean')):   # the hold task's
        for key in ('holding', 'holding_clean'):
            out[key] = _count(f, key, where, runs)
        for key, high in (('hold_fraction_mean', 1), ('hold_fraction_std', 1),
                          ('rail_contacts_mean', MAX_COUNT)):
            out[key] = schema.number(schema.field(f, key, where), f'{where}.{key}', low=0,
                                     high=high)
        out['hold_fraction_ci95'] = _ci(f.get('hold_fraction_ci95'),
                                        f'{where}.hold_fraction_ci95', 0, 1)
        first = f.get('first_entry_mean')
        out['first_entry_mean'] = None if first is None else schema.number(
            first, f'{where}.first_entry_mean', 0, MAX_COUNT)
    return out


def _curve(doc: Any, where: str, length: int, key: str) -> dict:
    """A curve over the grid: mean and std per grid point (nan for null)."""
    c = schema.mapping(doc, where)
    return {part: schema.numbers(schema.field(c, part, where), f'{where}.{part}', MAX_GRID,
                                 length=length, null=True, low=low, high=high)
            for part, low, high in _parts(key)}


def check_summary(doc: Any, where: str) -> dict:
    """One experiment's summary, checked."""
    s = schema.mapping(doc, where)
    get = lambda key: schema.field(s, key, where)   # noqa: E731
    steps = schema.integer(get('steps'), f'{where}.steps', 1, MAX_STEPS)
    grid = schema.numbers(get('grid'), f'{where}.grid', MAX_GRID, min_len=1, low=0,
                          high=steps)
    seeds = schema.integers(get('seeds'), f'{where}.seeds', MAX_SEEDS, 0, MAX_SEEDS)
    method = schema.text(get('method'), f'{where}.method')
    if method not in METHODS:
        raise DataFileError(f'{where}.method: expected one of {", ".join(METHODS)}, '
                            f'got {method[:40]!r}')
    out = {'id': schema.integer(get('id'), f'{where}.id', 0, MAX_SEEDS),
           'problem': configured_problem(get('problem'), f'{where}.problem').name,
           'method': method,
           'delta': schema.number(get('delta'), f'{where}.delta', DELTA.low, DELTA.high),
           'steps': steps, 'seeds': seeds, 'grid': grid,
           **{key: _curve(get(key), f'{where}.{key}', len(grid), key)
              for key in ('best_value', 'delta_star')},
           'achieved_fraction': schema.numbers(get('achieved_fraction'),
                                               f'{where}.achieved_fraction', MAX_GRID,
                                               length=len(grid), low=0, high=1),
           'final': _final(get('final'), f'{where}.final', len(seeds))}
    for key, default, pattern in (('style', 'state-action', WORD), ('variant', 'paper', WORD),
                                  ('catch', 'none', WORD), ('disturbance', 'none', None),
                                  ('group', 'paper', WORD), ('paper', '', None)):
        out[key] = schema.text(s.get(key, default), f'{where}.{key}', pattern=pattern)
    out['episodes'] = schema.integer(s.get('episodes', 1), f'{where}.episodes', 1,
                                     MAX_EPISODES)
    out['redraw'] = schema.boolean(s.get('redraw', False), f'{where}.redraw')
    out['catch_delay'] = schema.integer(s.get('catch_delay', 0), f'{where}.catch_delay', 0,
                                        MAX_DELAY)
    out['delay'] = schema.integer(s.get('delay', 0), f'{where}.delay', 0, MAX_DELAY)
    return out


def read_summary(path: str | os.PathLike) -> list[dict]:
    """The checked summaries of ``summary.json``."""
    doc = schema.sequence(read_json(path, MAX_SUMMARY_BYTES), str(path), MAX_EXPERIMENTS)
    return [check_summary(s, f'{path}: [{i}]') for i, s in enumerate(doc)]


def read_info(path: str | os.PathLike) -> dict:
    """The checked ``experiment.json`` (what the last invocation ran)."""
    where = str(path)
    doc = schema.mapping(read_json(path, MAX_INFO_BYTES), where)
    checks = {'name': lambda v, w: schema.text(v, w, 80),
              'command': lambda v, w: schema.text(v, w, 4000),
              'backend': lambda v, w: schema.text(v, w, 40),
              'wall_s': lambda v, w: schema.number(v, w, 0),
              'seeds': lambda v, w: schema.integer(v, w, 1, MAX_SEEDS),
              'scale': lambda v, w: schema.number(v, w, 0),
              'runs_run': lambda v, w: schema.integer(v, w, 0, 10 ** 9),
              'runs_reused': lambda v, w: schema.integer(v, w, 0, 10 ** 9)}
    return {key: check(doc[key], f'{where}: {key}') for key, check in checks.items()
            if key in doc}
