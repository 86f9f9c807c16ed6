"""The run files of an experiment directory (``DIR/runs/<id>-seed<seed>.json``), read as
hostile input.

A run file holds ``{"key": ..., "run": ...}``: the settings the run depends on and what it
produced (the log curves, the final measures, the best policy).  ``read_run`` checks every
field the engine and the report use (types, lengths, finiteness, ranges) within bounded
memory (``sapga_ros.io.jsonfile``); a file that fails is a ``DataFileError`` naming the file
and the field.  ``run_state`` tells the engine what a resume does with a file: reuse it,
run it again (absent or damaged), or refuse to mix in a run of other settings.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, Iterator

from sapga_ros.errors import ConfigError, DataFileError
from sapga_ros.io import schema
from sapga_ros.io.jsonfile import read_json
from sim_nodes.errors import UnknownProblemError
from sim_nodes.problem import Problem, load_problem

MAX_RUN_BYTES = 16 << 20       # a run of 30 M steps with its policy is about 10 kB
MAX_RUN_VALUES = 500_000
MAX_ROWS = 100_000             # log rows of one run
MAX_COUNT = 10 ** 15
MAX_VALUE = 1e9                # |value| of a return (real runs: of order 1e4)
MAX_DELTA_STAR = 1e9           # delta* (real runs: below 10; a goal scaled small: large)


PROBLEM_NAME = r'[a-z][a-z0-9_]{0,79}'


def configured_problem(value: Any, where: str) -> Problem:
    """The configured problem a file names at ``where`` (its policies and actions are read
    against it); one ``DataFileError`` line otherwise."""
    name = schema.text(value, where, pattern=PROBLEM_NAME)
    try:
        return load_problem(name)
    except UnknownProblemError as exc:
        raise DataFileError(f'{where}: {exc}') from None


def run_path(out: Path, exp_id: int, seed: int) -> Path:
    return out / 'runs' / f'{exp_id}-seed{seed}.json'


def bounds(key: str) -> tuple[float, float]:
    """[low, high] of the values of measure ``key``: a delta* or a value (a return); what a
    summary's figures can draw."""
    return (0.0, MAX_DELTA_STAR) if 'delta_star' in key else (-MAX_VALUE, MAX_VALUE)


def _curve(run: dict, key: str, where: str, rows: int | None, null: bool) -> list[float]:
    return schema.numbers(schema.field(run, key, where), f'{where}.{key}', MAX_ROWS,
                          length=rows, null=null, min_len=1, low=bounds(key)[0],
                          high=bounds(key)[1])


def _measure(f: dict, key: str, where: str) -> float:
    """A final measure (nan for null) within ``bounds(key)``."""
    return schema.number(schema.field(f, key, where), f'{where}.{key}', *bounds(key),
                         null=True)


def check_run(doc: Any, where: str, seed: int | None = None) -> dict:
    """The run record of a run file's ``run`` field, checked (nan for JSON null)."""
    run = schema.mapping(doc, where)
    got_seed = schema.integer(schema.field(run, 'seed', where), f'{where}.seed', 0, MAX_COUNT)
    if seed is not None and got_seed != seed:
        raise DataFileError(f'{where}.seed: expected {seed}, got {got_seed}')
    steps = schema.integers(schema.field(run, 'steps', where), f'{where}.steps', MAX_ROWS,
                            0, MAX_COUNT, min_len=1)
    if any(b < a for a, b in zip(steps, steps[1:])):
        raise DataFileError(f'{where}.steps: expected non-decreasing step counts')
    best = _curve(run, 'best_value', where, len(steps), True)
    dstar = _curve(run, 'delta_star', where, len(steps), True)
    fw = f'{where}.final'
    f = schema.mapping(schema.field(run, 'final', where), fw)
    final = {'best_value': _measure(f, 'best_value', fw),
             'delta_star': _measure(f, 'delta_star', fw),
             'achieved': schema.boolean(schema.field(f, 'achieved', fw), f'{fw}.achieved')}
    if 'steps_per_s' in f:
        final['steps_per_s'] = schema.number(f['steps_per_s'], f'{fw}.steps_per_s', low=0,
                                             null=True)
    for key in ('delta_star_alt', 'greedy_delta_star', 'greedy_value'):
        if key in f:
            final[key] = _measure(f, key, fw)
    if 'policy_value' in f or 'policy_delta_star' in f:   # the returned policy's episode
        for key in ('policy_value', 'policy_delta_star'):
            final[key] = _measure(f, key, fw)
        final['policy_reached'] = schema.boolean(schema.field(f, 'policy_reached', fw),
                                                 f'{fw}.policy_reached')
        final['policy_rail_contacts'] = schema.integer(
            schema.field(f, 'policy_rail_contacts', fw), f'{fw}.policy_rail_contacts', 0,
            MAX_COUNT)
    if 'hold_fraction' in f:       # the hold measures of the returned policy's episode
        final['hold_fraction'] = schema.number(f['hold_fraction'], f'{fw}.hold_fraction',
                                               low=0, high=1)
        first = schema.field(f, 'first_entry_step', fw)
        final['first_entry_step'] = None if first is None else schema.integer(
            first, f'{fw}.first_entry_step', 0, MAX_COUNT)
        final['rail_contacts'] = schema.integer(schema.field(f, 'rail_contacts', fw),
                                                f'{fw}.rail_contacts', 0, MAX_COUNT)
    record = {'seed': got_seed, 'steps': steps, 'best_value': best, 'delta_star': dstar,
              'final': final,
              'seconds': schema.number(run.get('seconds', 0.0), f'{where}.seconds', 0),
              'lanes': schema.integer(run.get('lanes', 1), f'{where}.lanes', 1, MAX_COUNT)}
    if run.get('policy') is not None:
        record['policy'] = schema.mapping(run['policy'], f'{where}.policy')
    return record


def read_run(path: Path, seed: int | None = None) -> tuple[Any, dict]:
    """(key, checked run record) of the run file ``path``; DataFileError if malformed."""
    doc = schema.mapping(read_json(path, MAX_RUN_BYTES, MAX_RUN_VALUES), str(path))
    key = schema.mapping(schema.field(doc, 'key', str(path)), f'{path}: key')
    return key, check_run(schema.field(doc, 'run', str(path)), f'{path}: run', seed)


def stored_runs(out: Path, exp_id: int, seeds: list[int]) -> Iterator[tuple[int, dict]]:
    """(seed, checked run record) of each of ``seeds`` whose run file ``out/runs/`` holds,
    read one at a time."""
    for seed in seeds:
        path = run_path(out, exp_id, seed)
        if path.exists():
            yield seed, read_run(path, seed)[1]


def run_state(path: Path, key: dict, seed: int) -> tuple[dict | None, str]:
    """What a resume does with the run file at ``path``: (record, '') to reuse it,
    (None, reason) to run it again (reason '' when there is no file).  ConfigError for a
    run of other settings (never mixed in) or a path that a run file cannot replace."""
    try:
        mode = os.lstat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None, ''
    if stat.S_ISLNK(mode):
        return None, f'{path}: a symbolic link, not a run file'
    if not stat.S_ISREG(mode):
        raise ConfigError(f'{path}: not a regular file; remove it to run it again')
    try:
        stored, record = read_run(path, seed)
    except DataFileError as exc:
        return None, str(exc)
    if stored != key:
        raise ConfigError(f'{path}: a run of other settings ({str(stored)[:200]}), not '
                          f'{key}; use another --out')
    return record, ''
