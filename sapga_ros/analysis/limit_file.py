"""The file of a physical-limit search (``sapga limit --out``, ``DIR/limits/*.json``):
written as strict JSON (a non-finite number, such as the nan goal scale of a coordinate with
a fixed bound or an infinite delta, is ``null``) and read back as hostile input: every field
the report uses is checked, one ``DataFileError`` line naming the file and the field.  The
file must fit its problem: a configured problem, actions from its action set, no more of
them than its episode's steps, a goal scale per state coordinate, and the alternative goal
reading only where the problem has one.
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict
from typing import Any

from sapga_ros.analysis.limit import Limit
from sapga_ros.errors import DataFileError
from sapga_ros.io import schema
from sapga_ros.io.jsonfile import read_json
from sapga_ros.training.run_files import MAX_DELTA_STAR, configured_problem
from sim_nodes.problem import Problem

MAX_LIMIT_BYTES = 16 << 20
MAX_ACTIONS = 10_000_000
MAX_COUNT = 10 ** 15


def limit_document(limit: Limit) -> dict[str, Any]:
    """The JSON document of ``limit`` (non-finite numbers are written as null)."""
    return asdict(limit)


def read_limit(path: str | os.PathLike) -> dict[str, Any]:
    """The checked document of a limit file (nan for null numbers)."""
    where = str(path)
    doc = schema.mapping(read_json(path, MAX_LIMIT_BYTES), where)
    get = lambda key: schema.field(doc, key, where)   # noqa: E731
    problem = configured_problem(get('problem'), f'{where}: problem')
    out = {'problem': problem.name,
           'delta': schema.number(get('delta'), f'{where}: delta', 0, MAX_DELTA_STAR,
                                  null=True),
           'step': schema.integer(get('step'), f'{where}: step', 0, problem.n_step),
           'width': schema.integer(get('width'), f'{where}: width', 1, MAX_COUNT),
           'cells': schema.integer(get('cells'), f'{where}: cells', 1, MAX_COUNT),
           'steps_simulated': schema.integer(get('steps_simulated'),
                                             f'{where}: steps_simulated', 0, MAX_COUNT),
           'actions': schema.numbers(get('actions'), f'{where}: actions', MAX_ACTIONS),
           'goal_scale': schema.numbers(get('goal_scale'), f'{where}: goal_scale', problem.dim,
                                        length=problem.dim, null=True, low=0),
           'alternative_goal': schema.boolean(doc.get('alternative_goal', False),
                                              f'{where}: alternative_goal')}
    if len(out['actions']) != out['step']:
        raise DataFileError(f'{where}: actions: expected {out["step"]} (step) items, '
                            f'got {len(out["actions"])}')
    _fits(problem, out, where)
    if 'seconds' in doc:
        out['seconds'] = schema.number(doc['seconds'], f'{where}: seconds', 0)
    return out


def _fits(problem: Problem, doc: dict, where: str) -> None:
    """DataFileError unless the actions are the problem's and its goal reading exists."""
    allowed = set(problem.actions)
    for i, a in enumerate(doc['actions']):
        if a not in allowed:
            raise DataFileError(f'{where}: actions[{i}]: expected one of '
                                f'{", ".join(f"{v:g}" for v in problem.actions)} (the '
                                f'actions of {problem.name}), got {a!r}')
    if doc['alternative_goal'] and problem.goal_alt_scale is None:
        raise DataFileError(f'{where}: alternative_goal: {problem.name} has no alternative '
                            'goal reading')


def delta_text(delta: float) -> str:
    """The delta of a limit for a table (``inf`` when no state met the fixed bounds)."""
    return f'{delta:.5f}' if math.isfinite(delta) else 'none found'
