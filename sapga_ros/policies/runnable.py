"""The policies a selector runs, read from their one file form ``sapga-policy/1``: exemplar
policies of any style, alone (``exemplar``; with a ``delay`` field, selecting on the state
predicted that many MDP steps ahead), behind an LQR catch (the hybrid: a ``catch``
field) or the classical controller (``kind: classical``, no exemplars) (``classical``).

Every reader of a policy the episode engine or the policy node runs comes through here, so
a hybrid never loses its catch on the way.
"""
from __future__ import annotations

import os
from typing import Any

from sapga_ros.errors import PolicyFileError
from sapga_ros.policies.classical import attach_catch, classical_from_document, run_ahead
from sapga_ros.policies.exemplar import BULK, ExemplarPolicy, exemplar_from_document
from sapga_ros.policies.jsonfile import as_text, excerpt, read_policy_text
from sapga_ros.policies.jsonstream import complete, read_document
from sim_nodes.problem import Problem


def policy_from_document(doc: Any, problem: str | Problem | None = None,
                         source: str = 'policy') -> ExemplarPolicy:
    """Validate a parsed policy document; ``problem`` (if given) must match its problem."""
    if isinstance(doc, dict) and 'kind' in doc:    # a controller, not exemplars
        if doc['kind'] != 'classical':
            raise PolicyFileError(f'{source}: kind: {excerpt(doc["kind"])} is not supported '
                                  '(supported: classical)')
        doc = complete(doc)
        if 'delay' in doc:
            raise PolicyFileError(f'{source}: delay: a classical policy\'s delay is its '
                                  'controller\'s (controller.delay)')
        return classical_from_document(doc, problem, source)
    policy = exemplar_from_document(doc, problem, source, controlled=True)
    if 'catch' in doc:            # the hybrid: the LQR catches inside x'Px <= c
        if 'delay' in doc:
            raise PolicyFileError(f'{source}: delay: a hybrid\'s delay is its catch\'s '
                                  '(catch.delay)')
        return attach_catch(policy, doc['catch'], source)
    if 'delay' in doc:            # the selector acts on the state predicted that far ahead
        return run_ahead(policy, doc['delay'], source)
    return policy


def policy_from_json(text: str | bytes, problem: str | Problem | None = None,
                     source: str = 'policy') -> ExemplarPolicy:
    """Parse and validate a policy document from its JSON text (exemplars read one at a
    time: ``sapga_ros.policies.jsonstream``)."""
    return policy_from_document(read_document(as_text(text, source), source, BULK), problem,
                                source)


def load_policy(path: str | os.PathLike, problem: str | Problem | None = None) -> ExemplarPolicy:
    """Read and validate a policy file (size-checked before it is read)."""
    return policy_from_document(read_document(read_policy_text(path), str(path), BULK),
                                problem, str(path))
