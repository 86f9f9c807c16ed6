"""Mismatched plants step all lanes at once (``step_lanes_each``, row k of a parameter
array for lane k), bit for bit what stepping each lane alone with its own parameters
gives; a disturbed evaluation with parameter mismatch gives, bit for bit, what the engine
gave when it stepped such lanes one at a time (digests recorded from that engine)."""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.disturbance import load_disturbance
from sim_nodes.models import MODELS, model_id, model_module
from sim_nodes.models.dispatch import lane_by_lane, step_lanes_each
from sim_nodes.problem import load_problem

PROBLEM_OF = {'acrobot': 'acrobot', 'pdip': 'pdip', 'pendulum': 'pendulum',
              'mountain_car': 'mountain_car'}


@pytest.mark.parametrize('model', MODELS)
def test_each_lane_steps_as_it_would_alone(model):
    problem = load_problem(PROBLEM_OF[model])
    p = problem.params()
    rng = np.random.default_rng(11)
    width, n = 16, 13                                  # lanes n.. are left alone
    S = rng.uniform(problem.low, problem.high, size=(width, problem.dim)).T.copy()
    P = p * (1.0 + rng.uniform(-0.2, 0.2, size=(width, len(p))))
    P[:, :2] = p[:2]                                   # dt and substeps: never mismatched
    alone = lane_by_lane(model_module(model).mdp_step_lanes)
    ref = S.copy()
    r, r_ref = np.full(width, 7.0), np.full(width, 7.0)
    for _ in range(30):
        action = rng.choice(problem.action_values, size=width)
        step_lanes_each(model_id(model), S, action, P, n, r)
        alone(ref, action, P, n, r_ref)
        np.testing.assert_array_equal(S, ref)
        np.testing.assert_array_equal(r, r_ref)
    assert not np.array_equal(S[:, 0], S[:, 1])        # the lanes did move apart


# problem -> (mismatch, digest of returns, steps and delta* recorded from the engine that
# stepped mismatched lanes one at a time)
RECORDED = {
    'acrobot': ({'masses': 0.1, 'lengths': 0.1, 'g': 0.2}, '87049ab5e69d022c'),
    'pdip': ({'masses': 0.1, 'lengths': 0.1, 'rail_penalty': 0.5}, '74ee5824d5ba3d18'),
    'pendulum': ({'m': 0.2, 'l': 0.1, 'b': 0.5}, 'add1c3bc3cb16b82'),
    'mountain_car': ({'power': 0.2, 'gravity': 0.2}, 'fc2e1c8b0180ca85'),
    'acrobot_hold': ({'masses': 0.1}, '1577f10c2456ef51'),
}


@pytest.mark.parametrize('name', sorted(RECORDED))
def test_mismatched_evaluation_is_the_recorded_one(name):
    mismatch, digest = RECORDED[name]
    problem = load_problem(name)
    rng = np.random.default_rng(7)
    policies = [random_exemplars(problem, 30, rng) for _ in range(37)]
    dist = dataclasses.replace(load_disturbance('field'), mismatch=mismatch, pushes=2,
                               push_size=0.3, gain=0.1)
    keys = np.array([[3, 0, k, k % 5] for k in range(len(policies))])
    r = Evaluator(problem, None, disturbance=dist).evaluate(policies, keys)
    got = hashlib.sha256(r.returns.tobytes() + r.steps.tobytes()
                         + r.delta_star.tobytes()).hexdigest()[:16]
    assert got == digest
