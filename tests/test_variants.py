"""SAP-GA variants (issue 8): the paper's algorithm stays the default and unchanged
(tests/test_pinned.py); each variant changes only which family member survives."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.sapga import VARIANTS, SapGA, SapgaParams
from sim_nodes.problem import load_problem


def one_generation(variant: str, seed: int = 3):
    """A small population after one generation, with the family members it chose from."""
    problem = load_problem('pdip')
    ga = SapGA.create(problem, SapgaParams(n_pop=8, n_child=4, variant=variant), seed)
    ev = Evaluator(problem, 0.01, n_step=80)
    batch = ga.ask()
    families = [(i, j, list(members)) for i, j, members in ga._families]
    r = ev.evaluate(batch)
    ga.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)
    return ga, families


@pytest.mark.parametrize('variant', list(VARIANTS))
def test_the_survivor_is_the_best_member_by_the_variants_rule(variant):
    """paper: best value, a parent among equals; dstar: smallest episode delta*, value next;
    *-child: a child among equals."""
    ga, families = one_generation(variant)
    for i, j, members in families:
        survivor = ga.population[i]
        if variant.startswith('dstar'):
            key = [(-m.delta_star, m.value) for m in members]
        else:
            key = [m.value for m in members]
        best = max(key)
        winners = [k for k, v in enumerate(key) if v == best]
        prefer_child = 'child' in variant and any(k >= 2 for k in winners)
        want = min(k for k in winners if k >= 2) if prefer_child else winners[0]
        assert survivor is members[want]


def test_dstar_variants_report_the_member_nearest_the_goal():
    """The run's result under dstar is the evaluated policy of smallest delta*; the logged
    best value is still the largest value seen."""
    ga, families = one_generation('dstar')
    evaluated = [m for _, _, members in families for m in members if not math.isnan(m.value)]
    assert ga.result.meta['delta_star'] == min(m.delta_star for m in evaluated)
    assert ga.stats.best_value == max(m.value for m in evaluated)


def test_unknown_variants_are_refused():
    """A variant name that does not exist is a one-line settings error."""
    with pytest.raises(Exception, match='variant'):
        SapgaParams(variant='telepathy')
    assert np.all([v for v in VARIANTS.values()])
