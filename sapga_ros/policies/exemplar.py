"""Exemplar policies and their file format ``sapga-policy/1``.

A policy is a set of exemplar records plus the action selector of its ``style``
(``sapga_ros.policies.styles``).  In memory, one row per exemplar: ``states`` (L, D) raw
float64 with angles wrapped to [0, 2pi), ``states2`` (L, D) for state-state (else (L, 0)),
``actions`` (L,) integer indices into the problem's action set and ``values`` (L,) (zeros
where the style has none).  On disk: a UTF-8 JSON document
``sapga-policy/1`` that a person can read, diff and edit.  Loading parses (never
evaluates), refuses NaN/Infinity literals, oversized files and every inconsistency with the
problem's configuration, naming the field that is wrong.
"""
from __future__ import annotations

import json
import math
import os
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from sapga_ros.errors import PolicyFileError, SapgaError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.policies.jsonfile import excerpt, finite, json_safe, meta_of
from sapga_ros.policies.jsonstream import Bulk, complete, require
from sapga_ros.policies.styles import STYLES, style_named
from sim_nodes.problem import Problem, load_problem

FORMAT = 'sapga-policy/1'
BULK = frozenset({'exemplars'})            # read one exemplar at a time
HEADER = ('format', 'problem', 'style', 'state_names', 'actions', 'exemplars')


@dataclass
class ExemplarPolicy:
    """An exemplar policy of one problem, in one style."""

    problem: Problem
    states: np.ndarray                       # (L, D) float64, angles in [0, 2pi)
    actions: np.ndarray | None = None        # (L,) int64 indices into problem.actions
    meta: dict[str, Any] = field(default_factory=dict)
    style: str = 'state-action'
    values: np.ndarray | None = None         # (L,) float64
    states2: np.ndarray | None = None        # (L, D) float64 (state-state), else (L, 0)

    def __post_init__(self) -> None:
        spec = style_named(self.style)
        dim = self.problem.dim
        self.states = self._wrapped(self.states)
        count = len(self.states)
        self.actions = np.ascontiguousarray(
            np.zeros(count) if self.actions is None else self.actions,
            dtype=np.int64).reshape(-1)
        self.values = np.ascontiguousarray(
            np.zeros(count) if self.values is None else self.values,
            dtype=np.float64).reshape(-1)
        if spec.uses('state2'):
            if self.states2 is None:
                raise SapgaError(f'a {self.style} policy needs second states')
            self.states2 = self._wrapped(self.states2)
        else:
            self.states2 = np.zeros((count, 0))
        for name, arr in (('actions', self.actions), ('values', self.values),
                          ('second states', self.states2)):
            if len(arr) != count:
                raise SapgaError(f'policy has {count} states but {len(arr)} {name}')
        if dim and self.states2.shape[1] not in (0, dim):
            raise SapgaError(f'second states have {self.states2.shape[1]} coordinates')

    def _wrapped(self, states) -> np.ndarray:
        states = np.ascontiguousarray(states, dtype=np.float64).reshape(-1, self.problem.dim)
        angle = self.problem.is_angle
        states[:, angle] = np.mod(states[:, angle], 2 * math.pi)
        states[:, angle] = np.where(states[:, angle] >= 2 * math.pi, 0.0, states[:, angle])
        return states

    def __len__(self) -> int:
        return len(self.states)

    @property
    def action_values(self) -> np.ndarray:
        return self.problem.action_values[self.actions]

    @classmethod
    def of_valid(cls, problem: Problem, states: np.ndarray, actions: np.ndarray, style: str,
                 values: np.ndarray, states2: np.ndarray) -> ExemplarPolicy:
        """A policy of arrays already in the form ``__post_init__`` makes (taken from valid
        policies): no checks, no copies.  The operators' hot path."""
        policy = cls.__new__(cls)
        policy.problem, policy.states, policy.actions = problem, states, actions
        policy.meta, policy.style, policy.values, policy.states2 = {}, style, values, states2
        return policy

    def subset(self, index) -> ExemplarPolicy:
        """The policy of the exemplars ``index`` (a mask or indices), in that order."""
        return ExemplarPolicy.of_valid(self.problem, self.states[index], self.actions[index],
                                       self.style, self.values[index], self.states2[index])

    def records(self) -> np.ndarray:
        """(L, K) float64: each exemplar's record, every field the style uses, in a row."""
        spec = STYLES[self.style]
        cols = [self.states]
        if spec.uses('state2'):
            cols.append(self.states2)
        if spec.uses('action'):
            cols.append(self.actions.astype(np.float64)[:, None])
        if spec.uses('value'):
            cols.append(self.values[:, None])
        return np.ascontiguousarray(np.column_stack(cols))

    def exemplar_document(self, j: int) -> dict[str, Any]:
        """Exemplar j as it is written in a policy file."""
        keys = STYLES[self.style].keys
        doc: dict[str, Any] = {}
        for name, key in keys.items():
            if name == 'state':
                doc[key] = [float(x) for x in self.states[j]]
            elif name == 'state2':
                doc[key] = [float(x) for x in self.states2[j]]
            elif name == 'action':
                doc[key] = self.problem.actions[self.actions[j]]
            else:
                doc[key] = float(self.values[j])
        return doc

    def to_document(self) -> dict[str, Any]:
        """The JSON document of the policy file (format ``sapga-policy/1``)."""
        return {
            'format': FORMAT,
            'problem': self.problem.name,
            'style': self.style,
            'state_names': list(self.problem.state_names),
            'actions': list(self.problem.actions),
            'exemplars': [self.exemplar_document(j) for j in range(len(self))],
            'meta': json_safe(self.meta),
        }

    def to_json(self) -> str:
        """Compact, one exemplar per line: readable and diff-friendly."""
        doc = self.to_document()
        exemplars = doc.pop('exemplars')
        head = json.dumps(doc, indent=1, allow_nan=False)[:-2]
        lines = ',\n  '.join(json.dumps(e, allow_nan=False) for e in exemplars)
        return head + ',\n "exemplars": [\n  ' + lines + '\n ]\n}\n'

    def save(self, path: str | os.PathLike, *, overwrite: bool = True) -> Path:
        """Write atomically (temporary file + rename): a crash never leaves half a file."""
        path = Path(path)
        if path.exists() and not overwrite:
            raise SapgaError(f'{path}: exists; refusing to overwrite')
        write_atomic(path, self.to_json())
        return path


def concat_policies(parts: list[ExemplarPolicy]) -> ExemplarPolicy:
    """One policy of every exemplar of ``parts`` (same problem and style), in order."""
    first = parts[0]
    if any(p.style != first.style or p.problem is not first.problem for p in parts):
        raise SapgaError('concatenated policies must share their problem and style')
    return ExemplarPolicy.of_valid(first.problem, np.concatenate([p.states for p in parts]),
                                   np.concatenate([p.actions for p in parts]), first.style,
                                   np.concatenate([p.values for p in parts]),
                                   np.concatenate([p.states2 for p in parts]))


def exemplar_from_document(doc: Any, problem: str | Problem | None = None,
                           source: str = 'policy', controlled: bool = False) -> ExemplarPolicy:
    """Validate the exemplar part of a parsed policy document; ``problem`` (if given) must
    match its problem.  A ``catch`` (or ``kind``) is refused unless ``controlled``: the
    reader of such documents is ``sapga_ros.policies.runnable``."""
    require(doc, HEADER, source)
    prob = document_problem(doc, problem, source)
    if not isinstance(doc['style'], str) or doc['style'] not in STYLES:
        raise PolicyFileError(f'{source}: style: {excerpt(doc["style"])} is not supported '
                              f'(supported: {", ".join(STYLES)})')
    spec = STYLES[doc['style']]
    if doc['state_names'] != list(prob.state_names):
        raise PolicyFileError(f'{source}: state_names: expected {list(prob.state_names)}, '
                              f'got {doc["state_names"]!r}'[:300])
    actions = doc['actions']
    if not isinstance(actions, list):
        raise PolicyFileError(f'{source}: actions: expected a list')
    values = [finite(a, f'{source}: actions[{i}]') for i, a in enumerate(actions)]
    if values != list(prob.actions):
        raise PolicyFileError(f'{source}: actions: expected {list(prob.actions)} for '
                              f'{prob.name}, got {values}')
    exemplars = doc['exemplars']
    if isinstance(exemplars, Bulk) and exemplars.kind == 'array':
        items: Iterable = exemplars.items()
    elif isinstance(exemplars, list):
        items = enumerate(exemplars)
    else:
        items = ()
    states, states2, vals = array('d'), array('d'), array('d')
    acts = array('q')
    index = {v: i for i, v in enumerate(values)}
    keys = spec.keys
    for j, e in items:
        where = f'{source}: exemplars[{j}]'
        if not isinstance(e, dict) or any(k not in e for k in keys.values()):
            wanted = ', '.join(f'"{k}"' for k in keys.values())
            raise PolicyFileError(f'{where}: expected an object with {wanted} '
                                  f'({spec.name} style)')
        for name, key in keys.items():
            if name in ('state', 'state2'):
                (states if name == 'state' else states2).extend(
                    _state(e[key], f'{where}.{key}', prob))
            elif name == 'action':
                a = finite(e[key], f'{where}.{key}')
                if a not in index:
                    raise PolicyFileError(f'{where}.{key}: {a} is not one of {values}')
                acts.append(index[a])
            else:
                vals.append(finite(e[key], f'{where}.{key}'))
    if not states:
        raise PolicyFileError(f'{source}: exemplars: expected a non-empty list')
    complete(doc)                           # the fields after the exemplars
    if 'kind' in doc:
        raise PolicyFileError(f'{source}: kind: a {excerpt(doc["kind"])} policy has no exemplars')
    if 'catch' in doc and not controlled:
        raise PolicyFileError(f'{source}: catch: a hybrid policy (read it with '
                              'sapga_ros.policies.runnable)')
    column = lambda a, kind: np.frombuffer(a, dtype=kind) if a else None  # noqa: E731
    policy = ExemplarPolicy(prob, column(states, np.float64), column(acts, np.int64),
                            meta=meta_of(doc, source), style=spec.name,
                            values=column(vals, np.float64),
                            states2=column(states2, np.float64) if spec.uses('state2') else None)
    return policy


def document_problem(doc: dict, problem: str | Problem | None, source: str) -> Problem:
    """The problem a policy document names, after checking its ``format``; ``problem`` (if
    given) must be that one."""
    if doc['format'] != FORMAT:
        raise PolicyFileError(f'{source}: format: expected {FORMAT!r}, '
                              f'got {excerpt(doc["format"])}')
    if not isinstance(doc['problem'], str):
        raise PolicyFileError(f'{source}: problem: expected a string')
    try:
        prob = load_problem(doc['problem'])
    except SapgaError as exc:
        raise PolicyFileError(f'{source}: problem: {exc}') from exc
    if problem is not None:
        want = problem if isinstance(problem, str) else problem.name
        if prob.name != want:
            raise PolicyFileError(f'{source}: problem: policy is for {prob.name!r}, '
                                  f'expected {want!r}')
    return prob


def _state(st: Any, where: str, prob: Problem) -> list[float]:
    """The coordinates of one state list of a policy file, validated."""
    dim = prob.dim
    if not isinstance(st, list) or len(st) != dim:
        got = len(st) if isinstance(st, list) else type(st).__name__
        raise PolicyFileError(f'{where}: expected {dim} numbers '
                              f'({", ".join(prob.state_names)}), got {got}')
    return [finite(x, f'{where}[{d}] ({prob.state_names[d]})') for d, x in enumerate(st)]
