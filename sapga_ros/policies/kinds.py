"""Every kind of policy file the package reads, told apart by its ``format`` field.

A kind is one module of this package (its policy class and file format) and one entry of
``KINDS``: the format string, the fields of its documents that are read an item at a time
(``sapga_ros.policies.jsonstream``) and the function that validates a parsed document.  A
policy of any kind has a ``problem``, a ``meta`` dict, ``to_json()`` / ``save(path)``, and
either is an ``ExemplarPolicy`` (run by the episode engine) or runs its own
``episode(delta, max_steps)`` (``sapga_ros.evaluation.evaluator.run_policy_episode``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Callable

from sapga_ros.errors import PolicyFileError
from sapga_ros.policies import exemplar, qtable, runnable
from sapga_ros.policies.jsonfile import as_text, excerpt, read_policy_text
from sapga_ros.policies.jsonstream import complete, read_document
from sim_nodes.params import DELTA
from sim_nodes.problem import Problem


@dataclass(frozen=True)
class Kind:
    """A policy file format: its name and the reader of a parsed document of it."""

    format: str
    summary: str
    from_document: Callable[[dict, str], Any]       # (document, source) -> policy
    bulk: frozenset[str] = frozenset()              # fields read an item at a time


KINDS: dict[str, Kind] = {k.format: k for k in (
    Kind(exemplar.FORMAT, 'exemplar policy (any exemplar style)',
         lambda doc, source: runnable.policy_from_document(doc, None, source), exemplar.BULK),
    Kind(qtable.FORMAT, 'greedy policy of a learnt Q-table', qtable.qtable_from_document,
         qtable.BULK),
)}
BULK = frozenset().union(*(k.bulk for k in KINDS.values()))


def any_policy_from_json(data: str | bytes, problem: str | Problem | None = None,
                         source: str = 'policy') -> Any:
    """The policy of a JSON document of any kind; ``problem`` (if given) must be its problem."""
    return _policy(read_document(as_text(data, source), source, BULK), problem, source)


def load_any_policy(path: str | os.PathLike, problem: str | Problem | None = None) -> Any:
    """A policy file of any kind (size-checked before it is read)."""
    return _policy(read_document(read_policy_text(path), str(path), BULK), problem, str(path))


def _policy(doc: dict, problem: str | Problem | None, source: str) -> Any:
    """The policy of a document, by its kind."""
    if 'format' not in doc:
        complete(doc)
    kind = KINDS.get(doc['format']) if isinstance(doc.get('format'), str) else None
    if kind is None:
        raise PolicyFileError(f'{source}: format: expected one of {", ".join(KINDS)}, got '
                              f'{excerpt(doc.get("format"))}')
    policy = kind.from_document(doc, source)
    want = problem if problem is None or isinstance(problem, str) else problem.name
    if want is not None and policy.problem.name != want:
        raise PolicyFileError(f'{source}: problem: policy is for {policy.problem.name!r}, '
                              f'expected {want!r}')
    return policy


def policy_delta(policy: Any, given: float | None = None) -> float:
    """The delta a policy's episode runs at: ``given``, else the policy's training delta
    (``meta.delta``, if a valid delta), else the problem's (``sapga eval`` and the launches
    alike)."""
    if given is None:
        meta = policy.meta.get('delta') if isinstance(policy.meta, dict) else None
        given = meta if DELTA.reason(meta) is None else None
    return policy.problem.resolve('delta', given)
