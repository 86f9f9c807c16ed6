"""The classical controller and the LQR catch as policies (policy ``kind`` ``classical``,
and an exemplar policy with a ``catch``).

A classical policy file::

    {"format": "sapga-policy/1", "kind": "classical", "problem": "acrobot_hold",
     "state_names": [...], "actions": [...],
     "controller": {"K": [D numbers], "P": [D rows of D numbers], "c": number,
                    "swing_up": {"law": "acrobot-energy", "gains": {...}},
                    "delay": 1},
     "meta": {...}}

``delay`` (optional, 0 when absent, written only when not 0) is the actuation delay in MDP
steps the controller is designed for: it remembers the commands in flight and acts on the
state predicted for when its command arrives (``sapga_ros.evaluation.control``).

A hybrid (exemplars + catch) is an ordinary exemplar policy document with one more field,
``"catch": {"K": [...], "P": [[...]], "c": number}`` (and ``delay``, as above).  An exemplar
policy designed for an actuation delay (no catch) has one more top-level field,
``"delay": d`` (1 to 16): its selector acts on the state predicted d MDP steps ahead from the
commands in flight.  All are parsed as hostile input: every number finite, every shape
checked, the law and gain names known; the error names the field.  In memory all are
``ControlledPolicy``: an ``ExemplarPolicy`` (no exemplars for the classical kind) with its
packed controller row ``control`` (``sapga_ros.evaluation.control``), so the episode engine,
the traced episode and the policy node run them like any exemplar policy.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from sapga_ros.errors import PolicyFileError
from sapga_ros.policies.exemplar import FORMAT, ExemplarPolicy, document_problem
from sapga_ros.policies.jsonfile import check_finite_tree, finite, json_safe
from sapga_ros.policies import controller_row as C
from sim_nodes.params import Param
from sim_nodes.problem import Problem

KIND = 'classical'
AHEAD_KIND = 'ahead'                # exemplars selecting on the predicted state
LAWS = {  # law -> (swing-up kind, gain names in order)
    'acrobot-energy': (C.SWING_ACROBOT, ('kp', 'kd', 'ke')),
    'cart-energy': (C.SWING_CART, ('ke', 'kx', 'kv')),
}

DELAY = Param('delay', 0, 'MDP steps of actuation delay the LQR is designed for: it acts on '
              'the state predicted that far ahead from the commands in flight; 0: none',
              low=0, high=C.MAX_DELAY)


RUN_DELAY = Param('delay', 0, 'run the exemplar policy as designed for N MDP steps of '
                  'actuation delay: its selector acts on the state predicted that far ahead '
                  'from the commands in flight (the nominal model); 0: as its file says',
                  low=0, high=C.MAX_DELAY)


@dataclass(frozen=True)
class Design:
    """A model's default classical design (chosen by a grid search on the hold problems'
    own episode from the initial state: docs/hold.md)."""

    law: str
    effort: float          # LQR R weight (``sapga_ros.policies.lqr``)
    basin_margin: float    # catch region c = this x the empirical basin (``basin_c``)
    gains: tuple           # swing-up gains, in LAWS order


DESIGNS = {
    'acrobot': Design('acrobot-energy', 1e-4, 16.0, (5.0, 0.0, 3.0)),
    'pdip': Design('cart-energy', 1.0, 2.0, (1.0, 10.0, 0.0)),
}


@dataclass
class ControlledPolicy(ExemplarPolicy):
    """An exemplar policy behind a controller (classical: no exemplars)."""

    kind: str = 'exemplar'                  # 'classical', 'exemplar' (a hybrid) or 'ahead'
    K: np.ndarray | None = None             # (D,) LQR gain
    P: np.ndarray | None = None             # (D, D) Riccati solution
    c: float = 0.0                          # catch region x'Px <= c
    law: str = ''                           # swing-up law (classical)
    gains: dict | None = None               # swing-up gains (classical)
    delay: int = 0                          # actuation delay designed for (MDP steps)

    @property
    def control(self) -> np.ndarray:
        """The packed controller row ``sapga_ros.evaluation.control.choose`` takes."""
        dim = self.problem.dim
        row = np.zeros(C.HEAD + dim + dim * dim)
        row[C.MODE] = {KIND: C.CLASSICAL, AHEAD_KIND: C.AHEAD}.get(self.kind, C.CATCH)
        row[C.C] = self.c
        if self.kind == KIND:
            kind, names = LAWS[self.law]
            row[C.SWING] = kind
            consts = swing_constants(self.problem, kind, [self.gains[n] for n in names])
            row[C.GAINS:C.GAINS + len(consts)] = consts
        row[C.HEAD:C.HEAD + dim] = self.K
        row[C.HEAD + dim:] = self.P.reshape(-1)
        row[C.DELAY] = self.delay
        return row

    def controller_document(self) -> dict[str, Any]:
        doc = {'K': [float(v) for v in self.K], 'P': [[float(v) for v in r] for r in self.P],
               'c': float(self.c)}
        if self.kind == KIND:
            doc['swing_up'] = {'law': self.law, 'gains': dict(self.gains)}
        if self.delay:
            doc['delay'] = self.delay
        return doc

    def to_json(self) -> str:
        if self.kind != KIND:
            return super().to_json()
        return json.dumps(self.to_document(), indent=1, allow_nan=False) + '\n'

    def to_document(self) -> dict[str, Any]:
        if self.kind == AHEAD_KIND:
            return {**super().to_document(), 'delay': self.delay}
        if self.kind != KIND:
            return {**super().to_document(), 'catch': self.controller_document()}
        pr = self.problem
        return {'format': FORMAT, 'kind': KIND, 'problem': pr.name,
                'state_names': list(pr.state_names), 'actions': list(pr.actions),
                'controller': self.controller_document(), 'meta': json_safe(self.meta)}


def swing_constants(problem: Problem, kind: int, gains: list[float]) -> list[float]:
    """The swing-up constants of ``control.swing_up`` from the model's physics."""
    ph = problem.physics
    if kind == C.SWING_ACROBOT:
        m1, m2, l1, lc1, lc2 = ph['m1'], ph['m2'], ph['l1'], ph['lc1'], ph['lc2']
        i1, i2, g = ph['I1'], ph['I2'], ph['g']
        g1, g2 = g * (m1 * lc1 + m2 * l1), g * m2 * lc2
        return [m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2) + i1 + i2, 2 * m2 * l1 * lc2,
                m2 * lc2 ** 2 + i2, m2 * l1 * lc2, m2 * lc2 ** 2 + i2, g1, g2, g1 + g2, *gains]
    m1, m2, l1, l2, g = ph['m1'], ph['m2'], ph['l1'], ph['l2'], ph['g']
    first = problem.state_names.index('theta1')
    return [m1 * l1, m2 * l2, 4 / 3 * m1 * l1 ** 2, 4 / 3 * m2 * l2 ** 2, g,
            g * (m1 * l1 + m2 * l2), *gains, float(first)]


def with_catch(policy: ExemplarPolicy, catch: ControlledPolicy,
               scale: float = 1.0) -> ControlledPolicy:
    """``policy`` handing over to the LQR of ``catch`` inside its x'Px <= c (c scaled by
    ``scale``: an evolved catch region); behind an ``ahead`` controller (``ahead``),
    ``policy`` selecting on the predicted state."""
    return ControlledPolicy(policy.problem, policy.states, policy.actions, policy.meta,
                            policy.style, policy.values,
                            policy.states2 if policy.states2.shape[1] else None,
                            kind=catch.kind if catch.kind == AHEAD_KIND else 'exemplar',
                            K=catch.K, P=catch.P, c=catch.c * scale, delay=catch.delay)


def ahead(policy: Any, delay: int) -> Any:
    """``policy`` designed for ``delay`` MDP steps of actuation delay: its selector acts on
    the state predicted that far ahead from the commands in flight (the nominal model's
    MDP step); ``delay`` 0, or the delay it is designed for already: ``policy`` itself.
    Only a plain exemplar policy takes a delay (a hybrid's or a classical policy's is its
    controller's)."""
    reason = DELAY.reason(delay)
    if reason:
        raise PolicyFileError(reason)
    if delay == 0:
        return policy
    if selector_delay(policy) == delay:   # the delay it is designed for already
        return policy
    if selector_delay(policy):
        raise PolicyFileError(f'delay: the policy is designed for a delay of {policy.delay} '
                              'MDP step(s) already (its file\'s delay)')
    if isinstance(policy, ControlledPolicy) or not isinstance(policy, ExemplarPolicy):
        raise PolicyFileError('delay: only a plain exemplar policy takes one (a hybrid or '
                              'classical policy predicts by its controller\'s own delay; a '
                              'Q-table acts on the state it sees)')
    dim = policy.problem.dim
    return with_catch(policy, ControlledPolicy(
        policy.problem, np.zeros((0, dim)), kind=AHEAD_KIND, K=np.zeros(dim),
        P=np.zeros((dim, dim)), c=0.0, delay=delay))


def selector_delay(policy: Any) -> int:
    """The delay a policy's exemplar selector is designed for (``ahead``; 0: none)."""
    return policy.delay if isinstance(policy, ControlledPolicy) and \
        policy.kind == AHEAD_KIND else 0


def is_classical(policy: Any) -> bool:
    """Whether ``policy`` is the classical controller (no exemplars)."""
    return isinstance(policy, ControlledPolicy) and policy.kind == KIND


def catch_delay(policy: Any) -> int | None:
    """The delay a hybrid's catch is designed for; None: not a hybrid."""
    return policy.delay if isinstance(policy, ControlledPolicy) and \
        policy.kind == 'exemplar' else None


def run_ahead(policy: Any, delay: int, source: str) -> Any:
    """``ahead`` for a policy read from ``source`` (a refusal names it)."""
    try:
        return ahead(policy, delay)
    except PolicyFileError as exc:
        raise PolicyFileError(f'{source}: {exc}') from None


def same_controller(policy: ExemplarPolicy, subset: ExemplarPolicy) -> ExemplarPolicy:
    """``subset`` (some of ``policy``'s exemplars) behind ``policy``'s controller, if it has
    one (a hybrid's catch, a delay's prediction): what ``policy`` runs, with fewer exemplars."""
    if isinstance(policy, ControlledPolicy) and policy.kind != KIND:
        return with_catch(subset, policy)
    return subset


def hybrid_of_valid(policy: ExemplarPolicy, catch: ControlledPolicy,
                    scale: float) -> ControlledPolicy:
    """``with_catch`` for a policy whose arrays are already valid (an operator's child, a
    population member): no checks, no copies, the arrays shared.  SAP-GA's hot path when
    the catch region evolves."""
    hybrid = ControlledPolicy.of_valid(policy.problem, policy.states, policy.actions,
                                       policy.style, policy.values, policy.states2)
    hybrid.meta, hybrid.kind, hybrid.law, hybrid.gains = policy.meta, 'exemplar', '', None
    hybrid.K, hybrid.P, hybrid.c, hybrid.delay = catch.K, catch.P, catch.c * scale, catch.delay
    return hybrid


def _vector(value: Any, length: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != length:
        raise PolicyFileError(f'{where}: expected a list of {length} numbers')
    return np.array([finite(v, f'{where}[{i}]') for i, v in enumerate(value)])


def _controller(doc: Any, problem: Problem, where: str, classical: bool) -> dict:
    if not isinstance(doc, dict):
        raise PolicyFileError(f'{where}: expected an object with K, P, c')
    for key in ('K', 'P', 'c') + (('swing_up',) if classical else ()):
        if key not in doc:
            raise PolicyFileError(f'{where}: missing field {key!r}')
    dim = problem.dim
    K = _vector(doc['K'], dim, f'{where}.K')
    rows = doc['P']
    if not isinstance(rows, list) or len(rows) != dim:
        raise PolicyFileError(f'{where}.P: expected {dim} rows of {dim} numbers')
    P = np.array([_vector(r, dim, f'{where}.P[{i}]') for i, r in enumerate(rows)])
    c = finite(doc['c'], f'{where}.c')
    if c < 0:
        raise PolicyFileError(f'{where}.c: expected a number >= 0, got {c}')
    out = {'K': K, 'P': P, 'c': c, 'delay': doc.get('delay', 0)}
    reason = DELAY.reason(out['delay'])
    if reason:
        raise PolicyFileError(f'{where}.{reason}')
    if classical:
        out.update(_swing_up(doc['swing_up'], f'{where}.swing_up'))
    return out


def _swing_up(doc: Any, where: str) -> dict:
    if not isinstance(doc, dict) or not isinstance(doc.get('law'), str) or \
            doc['law'] not in LAWS:
        raise PolicyFileError(f'{where}.law: expected one of {", ".join(LAWS)}')
    names = LAWS[doc['law']][1]
    gains = doc.get('gains')
    if not isinstance(gains, dict) or sorted(gains) != sorted(names):
        raise PolicyFileError(f'{where}.gains: expected an object with {", ".join(names)}')
    return {'law': doc['law'],
            'gains': {n: finite(gains[n], f'{where}.gains.{n}') for n in names}}


def classical_from_document(doc: dict, problem: str | Problem | None,
                            source: str) -> ControlledPolicy:
    """Validate a ``kind: classical`` policy document."""
    for key in ('format', 'problem', 'state_names', 'actions', 'controller'):
        if key not in doc:
            raise PolicyFileError(f'{source}: missing field {key!r}')
    prob = document_problem(doc, problem, source)
    if doc['state_names'] != list(prob.state_names):
        raise PolicyFileError(f'{source}: state_names: expected {list(prob.state_names)}')
    actions = doc['actions']
    if not isinstance(actions, list) or \
            [finite(a, f'{source}: actions') for a in actions] != list(prob.actions):
        raise PolicyFileError(f'{source}: actions: expected {list(prob.actions)}')
    design = DESIGNS.get(prob.model)
    ctl = _controller(doc['controller'], prob, f'{source}: controller', True)
    if design is None or ctl['law'] != design.law:
        raise PolicyFileError(f'{source}: controller.swing_up.law: {ctl["law"]} does not fit '
                              f'model {prob.model}')
    meta = doc.get('meta', {})
    if not isinstance(meta, dict):
        raise PolicyFileError(f'{source}: meta: expected an object')
    check_finite_tree(meta, f'{source}: meta')
    return ControlledPolicy(prob, np.zeros((0, prob.dim)), meta=meta, kind=KIND, **ctl)


def attach_catch(policy: ExemplarPolicy, doc: Any, source: str) -> ControlledPolicy:
    """An exemplar policy read from a document with a ``catch`` field."""
    ctl = _controller(doc, policy.problem, f'{source}: catch', False)
    return ControlledPolicy(policy.problem, policy.states, policy.actions, policy.meta,
                            policy.style, policy.values,
                            policy.states2 if policy.states2.shape[1] else None, **ctl)
