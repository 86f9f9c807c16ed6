"""The LQR catch region on a problem whose episode ends in S_delta (the paper's acrobot).

The region is measured by probe episodes that must run all their steps; on a problem whose
episode ends at the first entry into S_delta they used to end there, every probe counted as
a failure, and the region came out empty: the hybrid never caught.  Properties: the region
of such a problem is its hold twin's (same model, same delta); started inside it, outside
S_delta, the hybrid enters S_delta where the same policy without its catch does not; a
problem whose quantised LQR keeps S_delta from no probe start (the PDIP's three forces)
refuses ``--catch lqr`` with one line.
"""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.classical import with_catch
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.goal import delta_of
from sim_nodes.problem import load_problem


@pytest.mark.parametrize('delay', [0, 1])
def test_an_ends_in_goal_problem_has_its_hold_twins_catch_region(delay):
    reach = classical_policy(load_problem('acrobot'), delay=delay)
    hold = classical_policy(load_problem('acrobot_hold'), delay=delay)
    assert reach.c > 0
    assert reach.c == hold.c
    np.testing.assert_array_equal(reach.K, hold.K)


def _start_inside(problem, catch, share: float):
    """A start on x'Px = share c along the region's second-stiffest axis, outside S_delta
    (along its longest the quantised LQR does not hold: the design's c is a margin times
    the basin measured from probe starts)."""
    direction = np.linalg.eigh(catch.P)[1][:, 2]
    x = direction * np.sqrt(share * catch.c / (direction @ catch.P @ direction))
    start = dataclasses.replace(problem, initial=tuple(problem.best_state + x))
    assert delta_of(problem, np.asarray(start.initial)) > problem.default_delta
    return start


def test_started_inside_the_region_the_hybrid_enters_the_goal_and_the_bare_policy_not():
    problem = load_problem('acrobot')
    design = classical_policy(problem)
    start = _start_inside(problem, design, 0.1)
    bare = ExemplarPolicy(start, np.zeros((0, problem.dim)))
    hybrid = with_catch(bare, design)
    hybrid.problem = start
    caught = Evaluator(start).episode(hybrid)
    assert caught.reached and caught.steps < start.n_step
    assert caught.delta_star <= problem.default_delta
    alone = Evaluator(start).episode(bare)
    assert not alone.reached


def test_an_empty_catch_region_refuses_catch_lqr_with_one_line(tmp_path):
    r = subprocess.run([sys.executable, '-m', 'sapga_ros.cli.main', 'train', '--problem', 'pdip',
                        '--catch', 'lqr', '--steps', '20000', '--quiet',
                        '--out', str(tmp_path / 'p.json')],
                       capture_output=True, text=True, env={**os.environ}, timeout=300)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and 'catch region measured empty' in lines[0], r.stderr
    assert 'Traceback' not in r.stderr
    assert not (tmp_path / 'p.json').exists()
