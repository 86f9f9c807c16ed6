"""The classical controller designed for a problem: the LQR about the upright state (from
the model linearised at the compiled MDP step, ``sapga_ros.policies.lqr``) behind the model's
energy swing-up, with a catch region measured on the episode engine (``basin_c``; for a
controller designed for an actuation delay, on the plant with that delay).  The
policy kind and its file form are ``sapga_ros.policies.classical``; this module needs the
engine, so it lives beside it.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.classical import DESIGNS, KIND, LAWS, ControlledPolicy
from sapga_ros.policies.lqr import half_widths, inscribed_c, regulator
from sim_nodes.disturbance import Disturbance
from sim_nodes.goal import delta_of
from sim_nodes.problem import Problem


def classical_policy(problem: Problem, gains: dict | None = None, c: float | None = None,
                     effort: float | None = None, delay: int = 0) -> ControlledPolicy:
    """The LQR about the upright state behind the model's energy swing-up (``DESIGNS``;
    ``gains``, ``c`` and ``effort`` override the design's), designed for a plant that
    applies each command ``delay`` MDP steps late."""
    design = DESIGNS.get(problem.model)
    if design is None:
        raise SapgaError(f'{problem.name}: no classical design for model {problem.model!r} '
                         f'(known: {", ".join(DESIGNS)})')
    reg = regulator(problem, design.effort if effort is None else effort)
    names = LAWS[design.law][1]
    g = dict(zip(names, design.gains))
    for name, value in (gains or {}).items():
        if name not in g:
            raise SapgaError(f'unknown gain {name!r} of {design.law} (known: {", ".join(g)})')
        g[name] = float(value)
    policy = ControlledPolicy(problem, np.zeros((0, problem.dim)), kind=KIND, K=reg.K,
                              P=reg.P, c=0.0 if c is None else c, law=design.law, gains=g,
                              delay=delay, meta={'controller': 'LQR + energy swing-up'})
    if c is None:
        policy.c = design.basin_margin * basin_c(policy, problem.default_delta)
    return policy


def basin_c(policy: ControlledPolicy, delta: float, samples: int = 24, steps: int = 200,
            seed: int = 0) -> float:
    """The largest c of a halving ladder (from the ellipsoid inside S_1) such that the
    quantised LQR, started from ``samples`` states on x'Px = c, ends every episode of
    ``steps`` steps with its second half in S_delta: an empirical catch region
    (deterministic in ``seed``; the plant applies each command ``policy.delay`` steps
    late).  The probe episodes run all their steps whatever the problem's own episode end:
    on a problem whose episode ends in S_delta they would end at the first entry, and the
    region would be measured empty."""
    pr = policy.problem
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(samples, pr.dim)) * half_widths(pr)
    quad = np.einsum('ki,ij,kj->k', directions, policy.P, directions)
    unit = directions / np.sqrt(quad)[:, None]        # x'Px = 1
    c = inscribed_c(policy.P, pr, 1.0)
    probe = ControlledPolicy(pr, np.zeros((0, pr.dim)), kind=KIND, K=policy.K, P=policy.P,
                             c=np.inf, law=policy.law, gains=policy.gains, delay=policy.delay)
    late = Disturbance(latency=policy.delay) if policy.delay else None
    for _ in range(40):
        ok = True
        for x in unit * np.sqrt(c):
            start = dataclasses.replace(pr, initial=tuple(pr.best_state + x), n_step=steps,
                                        ends_in_goal=False)
            probe.problem = start
            ep = Evaluator(start, delta, disturbance=late).episode(probe)
            tail = ep.states[steps // 2:]
            if ep.steps < steps or ep.contacts or \
                    max(delta_of(pr, s) for s in tail) > delta:
                ok = False
                break
        if ok:
            return c
        c /= 2.0
    return 0.0
