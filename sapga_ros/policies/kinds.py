"""Every kind of policy file the package reads, told apart by its ``format`` field.

A kind is one module of this package (its policy class and file format) and one entry of
``KINDS``: the format string and the function that validates a parsed document of it.  A
policy of any kind has a ``problem``, a ``meta`` dict, ``to_json()`` / ``save(path)``, and
either is an ``ExemplarPolicy`` (run by the episode engine) or runs its own
``episode(delta, max_steps)`` (``sapga_ros.evaluation.evaluator.run_policy_episode``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Callable

from sapga_ros.errors import PolicyFileError
from sapga_ros.policies import exemplar, qtable
from sapga_ros.policies.jsonfile import excerpt, parse_json, read_policy_bytes
from sim_nodes.problem import Problem


@dataclass(frozen=True)
class Kind:
    """A policy file format: its name and the reader of a parsed document of it."""

    format: str
    summary: str
    from_document: Callable[[dict, str], Any]       # (document, source) -> policy


KINDS: dict[str, Kind] = {k.format: k for k in (
    Kind(exemplar.FORMAT, 'exemplar policy (any exemplar style)',
         lambda doc, source: exemplar.policy_from_document(doc, None, source)),
    Kind(qtable.FORMAT, 'greedy policy of a learnt Q-table', qtable.qtable_from_document),
)}


def any_policy_from_json(data: str | bytes, problem: str | Problem | None = None,
                         source: str = 'policy') -> Any:
    """The policy of a JSON document of any kind; ``problem`` (if given) must be its problem."""
    doc = parse_json(data, source)
    if not isinstance(doc, dict):
        raise PolicyFileError(f'{source}: expected a JSON object at the top level')
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


def load_any_policy(path: str | os.PathLike, problem: str | Problem | None = None) -> Any:
    """A policy file of any kind (size-checked before it is read)."""
    return any_policy_from_json(read_policy_bytes(path), problem, str(path))
