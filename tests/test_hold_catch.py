"""The hold planner's hand-over (``sapga_ros.evaluation.hold_catch``): the LQR takes over
where the model says it settles, not wherever x'Px is small.  The settling test agrees with
the episode engine running the quantised LQR from the same state, and the ellipsoid x'Px <= c
holds states from which the LQR does not settle."""
import dataclasses

import numpy as np

from sapga_ros.evaluation.evaluator import Evaluator, model_id
from sapga_ros.evaluation.hold_catch import GATE, HORIZON, SETTLE, HoldCatch, settles
from sapga_ros.policies.classical import KIND, ControlledPolicy
from sim_nodes.problem import load_problem


def engine_settles(problem, catch, s):
    """Whether the engine's quantised LQR (the classical controller with an unbounded
    region, no delay) from ``s`` ends its HORIZON steps inside SETTLE x c."""
    start = dataclasses.replace(problem, initial=tuple(s), n_step=HORIZON, ends_in_goal=False)
    lqr = ControlledPolicy(start, np.zeros((0, problem.dim)), kind=KIND, K=catch.K,
                           P=catch.P, c=np.inf, law='acrobot-energy',
                           gains={'kp': 0.0, 'kd': 0.0, 'ke': 0.0})
    ep = Evaluator(start, 0.02).episode(lqr)
    x = catch.offset(ep.states[-1])
    return ep.steps == HORIZON and float(x @ catch.P @ x) <= SETTLE * catch.c


def test_the_settling_test_is_the_engines_lqr_episode(rng):
    problem = load_problem('acrobot_hold')
    catch = HoldCatch(problem, 0)
    work = (np.empty((problem.dim, 1)), np.empty(1), np.empty(1))
    p = problem.params()
    # states inside the gate, in the ellipsoid's own directions
    u = rng.normal(size=(60, problem.dim))
    u /= np.sqrt(np.einsum('ki,ij,kj->k', u, catch.P, u))[:, None]
    starts = problem.best_state + u * np.sqrt(rng.uniform(0.0, 2.0, (60, 1)) * catch.c)
    decided = []
    for s in starts:
        mine = settles(model_id(problem.model), s, catch.K, catch.P, SETTLE * catch.c,
                       catch.actions, catch.best, problem.is_angle, p, HORIZON, *work)
        assert mine == engine_settles(problem, catch, s)
        decided.append(mine)
    # inside x'Px <= 2c the LQR settles from some states and not from others: the
    # ellipsoid alone does not say where it can take over
    assert 0 < sum(decided) < len(decided)
    assert settles(model_id(problem.model), catch.best, catch.K, catch.P, SETTLE * catch.c,
                   catch.actions, catch.best, problem.is_angle, p, HORIZON, *work)
    nan = np.full(problem.dim, np.nan)
    assert not settles(model_id(problem.model), nan, catch.K, catch.P, SETTLE * catch.c,
                       catch.actions, catch.best, problem.is_angle, p, HORIZON, *work)


def test_the_lqr_commands_only_where_it_settles(rng):
    problem = load_problem('acrobot_hold')
    catch = HoldCatch(problem, 1)
    p = problem.params()
    K, P = catch.K, catch.P
    seen = {True: 0, False: 0}
    for _ in range(200):
        u = rng.normal(size=problem.dim)
        s = problem.best_state + u / np.sqrt(u @ P @ u) * np.sqrt(rng.uniform(0, 1.5) * catch.c)
        x = catch.offset(s)
        ok = settles(catch.model, s, K, P, SETTLE * catch.c, catch.actions, catch.best,
                     problem.is_angle, p, HORIZON, *catch._work)
        command = catch.command(s, p)
        if ok:
            assert command == problem.action_values[
                int(np.argmin(np.abs(np.asarray(problem.action_values) + K @ x)))]
        else:
            assert command is None
        seen[ok] += 1
    assert seen[True] and seen[False]
    far = problem.best_state.copy()
    far[0] += 1.0                                     # outside the gate: not even tried
    x = catch.offset(far)
    assert float(x @ P @ x) > GATE * catch.c and catch.command(far, p) is None
