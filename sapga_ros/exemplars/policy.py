"""Exemplar policies and the public policy file format (SPEC 3.1, 3.3).

A state-action policy is a set of exemplars (s_j, a_j) plus the nearest-neighbour selector.
In memory: ``states`` (L, D) raw float64 with angles wrapped to [0, 2pi), and ``actions``
(L,) integer indices into the problem's action set.  On disk: a UTF-8 JSON document
``sapga-policy/1`` that a person can read, diff and edit.  Loading parses (never
evaluates), refuses NaN/Infinity literals, oversized files and every inconsistency with the
problem's configuration, naming the field that is wrong.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sapga_ros.errors import PolicyFileError, SapgaError
from sapga_ros.io.atomic import write_atomic
from sim_nodes.problem import Problem, load_problem

FORMAT = 'sapga-policy/1'
STYLES = ('state-action',)
MAX_POLICY_BYTES = 64 * 1024 * 1024  # a Q-learning export of 20^4 tiles is ~15 MB


@dataclass
class ExemplarPolicy:
    """A state-action exemplar policy of one problem."""

    problem: Problem
    states: np.ndarray                       # (L, D) float64, angles in [0, 2pi)
    actions: np.ndarray                      # (L,) int64 indices into problem.actions
    meta: dict[str, Any] = field(default_factory=dict)
    style: str = 'state-action'

    def __post_init__(self) -> None:
        self.states = np.ascontiguousarray(self.states, dtype=np.float64).reshape(
            -1, self.problem.dim)
        self.actions = np.ascontiguousarray(self.actions, dtype=np.int64).reshape(-1)
        if len(self.states) != len(self.actions):
            raise SapgaError(f'policy has {len(self.states)} states but {len(self.actions)} '
                             'actions')
        angle = self.problem.is_angle
        self.states[:, angle] = np.mod(self.states[:, angle], 2 * math.pi)
        self.states[:, angle] = np.where(self.states[:, angle] >= 2 * math.pi, 0.0,
                                         self.states[:, angle])

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def action_values(self) -> np.ndarray:
        return self.problem.action_values[self.actions]

    def to_document(self) -> dict[str, Any]:
        """The JSON document of SPEC 3.3."""
        values = self.problem.actions
        return {
            'format': FORMAT,
            'problem': self.problem.name,
            'style': self.style,
            'state_names': list(self.problem.state_names),
            'actions': list(values),
            'exemplars': [{'state': [float(x) for x in s], 'action': values[a]}
                          for s, a in zip(self.states, self.actions)],
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


def _reject_constant(name: str) -> float:
    """NaN/Infinity literals parse to floats; validation then names the field holding one."""
    return float(name)


def excerpt(value: Any, limit: int = 60) -> str:
    """A short repr of a (possibly huge, hostile) value for an error message."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + '...'


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no inf or NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def _check_finite_tree(value: Any, where: str, depth: int = 0) -> None:
    """Every number inside ``value`` (free-form meta) is finite."""
    if depth > 50:
        raise PolicyFileError(f'{where}: nested too deeply')
    if isinstance(value, float) and not math.isfinite(value):
        raise PolicyFileError(f'{where}: not a finite number ({json.dumps(value)})')
    if isinstance(value, dict):
        for k, v in value.items():
            _check_finite_tree(v, f'{where}.{k}', depth + 1)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_finite_tree(v, f'{where}[{i}]', depth + 1)


def _finite(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PolicyFileError(f'{where}: expected a number, got {excerpt(value, 40)}')
    try:
        number = float(value)
    except OverflowError:
        raise PolicyFileError(f'{where}: number too large ({excerpt(value, 40)})') from None
    if not math.isfinite(number):
        raise PolicyFileError(f'{where}: not a finite number ({json.dumps(number)})')
    return number


def policy_from_document(doc: Any, problem: str | Problem | None = None,
                         source: str = 'policy') -> ExemplarPolicy:
    """Validate a parsed policy document; ``problem`` (if given) must match its problem."""
    if not isinstance(doc, dict):
        raise PolicyFileError(f'{source}: expected a JSON object at the top level')
    for key in ('format', 'problem', 'style', 'state_names', 'actions', 'exemplars'):
        if key not in doc:
            raise PolicyFileError(f'{source}: missing field {key!r}')
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
    if doc['style'] not in STYLES:
        raise PolicyFileError(f'{source}: style: {excerpt(doc["style"])} is not supported '
                              f'(supported: {", ".join(STYLES)})')
    if doc['state_names'] != list(prob.state_names):
        raise PolicyFileError(f'{source}: state_names: expected {list(prob.state_names)}, '
                              f'got {doc["state_names"]!r}'[:300])
    actions = doc['actions']
    if not isinstance(actions, list):
        raise PolicyFileError(f'{source}: actions: expected a list')
    values = [_finite(a, f'{source}: actions[{i}]') for i, a in enumerate(actions)]
    if values != list(prob.actions):
        raise PolicyFileError(f'{source}: actions: expected {list(prob.actions)} for '
                              f'{prob.name}, got {values}')
    exemplars = doc['exemplars']
    if not isinstance(exemplars, list) or not exemplars:
        raise PolicyFileError(f'{source}: exemplars: expected a non-empty list')
    dim = prob.dim
    states = np.empty((len(exemplars), dim))
    acts = np.empty(len(exemplars), dtype=np.int64)
    index = {v: i for i, v in enumerate(values)}
    for j, e in enumerate(exemplars):
        where = f'{source}: exemplars[{j}]'
        if not isinstance(e, dict) or 'state' not in e or 'action' not in e:
            raise PolicyFileError(f'{where}: expected an object with "state" and "action"')
        st = e['state']
        if not isinstance(st, list) or len(st) != dim:
            got = len(st) if isinstance(st, list) else type(st).__name__
            raise PolicyFileError(f'{where}.state: expected {dim} numbers '
                                  f'({", ".join(prob.state_names)}), got {got}')
        for d, x in enumerate(st):
            states[j, d] = _finite(x, f'{where}.state[{d}] ({prob.state_names[d]})')
        a = _finite(e['action'], f'{where}.action')
        if a not in index:
            raise PolicyFileError(f'{where}.action: {a} is not one of {values}')
        acts[j] = index[a]
    meta = doc.get('meta', {})
    if not isinstance(meta, dict):
        raise PolicyFileError(f'{source}: meta: expected an object')
    _check_finite_tree(meta, f'{source}: meta')
    return ExemplarPolicy(prob, states, acts, meta=meta, style=doc['style'])


def policy_from_json(text: str | bytes, problem: str | Problem | None = None,
                     source: str = 'policy') -> ExemplarPolicy:
    """Parse and validate a policy document from its JSON text."""
    if isinstance(text, bytes):
        if len(text) > MAX_POLICY_BYTES:
            raise PolicyFileError(f'{source}: {len(text)} bytes, larger than the '
                                  f'{MAX_POLICY_BYTES // (1024 * 1024)} MB limit')
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as exc:
            raise PolicyFileError(f'{source}: not UTF-8 text (byte {exc.start})') from exc
    if len(text) > MAX_POLICY_BYTES:
        raise PolicyFileError(f'{source}: larger than the '
                              f'{MAX_POLICY_BYTES // (1024 * 1024)} MB limit')
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise PolicyFileError(f'{source}: malformed JSON ({exc.msg}, line {exc.lineno} '
                              f'column {exc.colno})') from exc
    except ValueError as exc:
        raise PolicyFileError(f'{source}: {exc}') from exc
    except RecursionError as exc:
        raise PolicyFileError(f'{source}: JSON nested too deeply') from exc
    return policy_from_document(doc, problem, source)


def load_policy(path: str | os.PathLike, problem: str | Problem | None = None) -> ExemplarPolicy:
    """Read and validate a policy file (size-checked before it is read)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_POLICY_BYTES:
            raise PolicyFileError(f'{path}: {size / 1e6:.1f} MB, larger than the '
                                  f'{MAX_POLICY_BYTES // (1024 * 1024)} MB limit')
        with open(path, 'rb') as f:
            data = f.read(MAX_POLICY_BYTES + 1)
    except OSError as exc:
        raise PolicyFileError(f'{path}: cannot read ({exc.strerror})') from exc
    return policy_from_json(data, problem, str(path))
