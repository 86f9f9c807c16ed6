"""Decision-time planning on top of a policy (``sapga_ros.evaluation.replan``): the plan's
score is the episode it stands for, improving never makes it worse, a planned episode on
the exact model enters S_delta when its plan said it would (or sooner), and the same
episodes come out of any thread count."""
import dataclasses
import math

import numpy as np
import pytest

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.evaluator import model_id
from sapga_ros.evaluation.hold_catch import HoldCatch
from sapga_ros.evaluation.replan import (FAR, PLAN_LANES, RESTART_AFTER, PlanningSelector,
                                         Replanner, first_plan, improve_plan, plan_scores,
                                         planned_episode, planned_episodes)
from sapga_ros.evaluation.replan_settings import ReplanSettings, planner_delay
from sapga_ros.optim.operators import random_exemplars
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.policies.classical import ahead
from sim_nodes.disturbance import Disturbance, Plant, load_disturbance
from sim_nodes.goal import goal_arrays, goal_delta, hold_measures
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.draws import episode_key
from sim_nodes.errors import ConfigError
from sim_nodes.problem import load_problem

EASY = 0.47        # the acrobot's goal box some random plans enter, some not
MIXED = {'acrobot': EASY, 'pdip': 0.3}


BOX = (np.zeros((1, 1)), 0.0)      # plan_scores' goal: S_delta, not an ellipsoid


def scores(problem, plans, s, t0, delta, ellipse=BOX):
    lanes, dim = len(plans), problem.dim
    out = np.empty(lanes)
    plan_scores(model_id(problem.model), s, plans, t0, plans.shape[1], problem.params(),
                np.asarray(problem.action_values, dtype=np.float64), *goal_arrays(problem),
                problem.is_angle, delta, *ellipse, np.empty((dim, lanes)), np.empty(lanes),
                np.empty(lanes), np.empty(lanes), out)
    return out


def score_alone(problem, plan, s, t0, delta, ellipse=BOX):
    """What plan_scores computes, one step at a time on one state (the goal S_delta, or
    with ``ellipse`` = (P, c), x'Px <= c about the best state, angles the short way)."""
    S, a, r = s.copy().reshape(-1, 1), np.empty(1), np.empty(1)
    best, inv_scale, fixed = goal_arrays(problem)
    P, c = ellipse
    dmin = math.inf
    for t in range(t0, len(plan)):
        a[0] = problem.action_values[plan[t]]
        step_lanes(model_id(problem.model), S, a, problem.params(), 1, r)
        if c > 0:
            x = S[:, 0] - problem.best_state
            x[problem.is_angle] = np.remainder(x[problem.is_angle] + math.pi,
                                               2 * math.pi) - math.pi
            d = float(x @ P @ x)
        else:
            d = goal_delta(S[:, 0], best, inv_scale, fixed, problem.is_angle)
        dmin = min(dmin, d)
        if d <= (c if c > 0 else delta):
            return t - t0 + 1
    return FAR * (1.0 + (dmin / c if c > 0 else dmin))


@pytest.mark.parametrize('name', ['acrobot', 'pdip'])
def test_plan_scores_are_the_episodes_of_the_plans(name, rng):
    problem = load_problem(name)
    n = 120
    plans = rng.integers(0, len(problem.action_values), size=(PLAN_LANES, n))
    plans[3] = plans[2]                              # equal plans, equal scores
    s = problem.initial_state.astype(np.float64)
    for delta, t0 in ((MIXED[name], 0), (MIXED[name], 40), (0.02, 7)):
        got = scores(problem, plans, s, t0, delta)
        want = [score_alone(problem, plans[k], s, t0, delta) for k in range(PLAN_LANES)]
        assert got.tolist() == want
        assert got[2] == got[3]
    mixed = scores(problem, plans, s, 0, MIXED[name])
    assert (mixed < FAR).any() and (mixed >= FAR).any()
    # a hold task's goal: the ellipsoid of the LQR it hands over to
    P = HoldCatch(load_problem(f'{name}_hold'), 0).P0
    for c in (50.0, 1e3, 1e5):
        got = scores(problem, plans, s, 0, 0.02, (P, c))
        want = [score_alone(problem, plans[k], s, 0, 0.02, (P, c)) for k in range(PLAN_LANES)]
        assert got == pytest.approx(want, rel=1e-12, abs=0)


@pytest.mark.parametrize('name', ['acrobot', 'pdip'])
def test_bounded_scores_decide_what_full_scores_decide(name, rng):
    """With a bound the stepping stops early: where the full scores' least is within the
    bound, that least and its lane are still the full scores' and every other score is above
    it; where it is not, every score is above the bound."""
    problem = load_problem(name)
    n, dim = 160, problem.dim
    s = problem.initial_state.astype(np.float64)
    P = HoldCatch(load_problem(f'{name}_hold'), 0).P0
    early = 0
    for trial in range(12):
        plans = rng.integers(0, len(problem.action_values), size=(PLAN_LANES, n))
        ellipse = BOX if trial % 2 else (P, 1e3)
        full = scores(problem, plans, s, 0, MIXED[name], ellipse)
        assert (full < FAR).any()
        for bound in (np.inf, -1.0, float(np.sort(full)[3]), float(full.min()) - 1.0, 2.0):
            got = np.empty(PLAN_LANES)
            plan_scores(model_id(problem.model), s, plans, 0, n, problem.params(),
                        np.asarray(problem.action_values, dtype=np.float64),
                        *goal_arrays(problem), problem.is_angle, MIXED[name], *ellipse,
                        np.empty((dim, PLAN_LANES)), np.empty(PLAN_LANES),
                        np.empty(PLAN_LANES), np.empty(PLAN_LANES), got, bound)
            if bound < 0:
                assert got.tolist() == full.tolist()
                continue
            within = bound if bound < FAR else np.inf
            if full.min() <= within:
                assert got.min() == full.min() and got.argmin() == full.argmin()
                rest = got != got.min()
                assert got[~rest].tolist() == full[~rest].tolist()
                assert (got[rest] > full.min()).all()
            else:
                assert (got > within).all()
            early += int((got != full).any())
    assert early > 0                      # the bound did stop some scoring early


def test_an_entry_after_far_steps_bounds_nothing(rng):
    """Plans longer than FAR steps: a plan that never enters can score below one entering
    after FAR steps, so such an entry must not stop the scoring (seeds where it did)."""
    problem = load_problem('acrobot')
    n, dim = 30_000, problem.dim
    s = problem.initial_state.astype(np.float64)
    late = 0
    for seed in (0, 4, 17, 29):
        plans = np.random.default_rng(seed).integers(0, 3, size=(PLAN_LANES, n))
        full = scores(problem, plans, s, 0, 0.02)
        got = np.empty(PLAN_LANES)
        plan_scores(model_id(problem.model), s, plans, 0, n, problem.params(),
                    np.asarray(problem.action_values, dtype=np.float64), *goal_arrays(problem),
                    problem.is_angle, 0.02, *BOX, np.empty((dim, PLAN_LANES)),
                    np.empty(PLAN_LANES), np.empty(PLAN_LANES), np.empty(PLAN_LANES), got,
                    np.inf)
        assert got.min() == full.min() and got.argmin() == full.argmin()
        entered = full == np.floor(full)        # entry steps; FAR (1 + delta*) otherwise
        late += int(entered.any() and not entered[full.argmin()])
    assert late > 0          # a never-entering plan did beat every (late) entry
    for seed in (0, 4):
        out = []
        for prune in (True, False):
            plan = np.random.default_rng(seed).integers(0, 3, size=n)
            got = improve_plan(model_id(problem.model), s, plan, 0, n, problem.params(),
                               np.asarray(problem.action_values, dtype=np.float64),
                               *goal_arrays(problem), problem.is_angle, 0.02, *BOX, 4, 100,
                               np.uint64(seed), prune)
            out.append((got, plan.tolist()))
        assert out[0] == out[1]


@pytest.mark.parametrize('name', ['acrobot', 'acrobot_hold'])
def test_pruned_rounds_keep_the_plans_full_scoring_keeps(name, rng):
    """improve_plan with its rounds pruned: the same plans and scores as scored in full,
    from states spread about the start, goals some plans reach and some do not."""
    problem = load_problem(name)
    n = 300
    ellipse = (HoldCatch(problem, 0).P0, 1e3) if name.endswith('hold') else BOX
    entered = 0
    for trial in range(8):
        s = problem.initial_state + rng.uniform(-0.05, 0.05, problem.dim)
        start = rng.integers(0, len(problem.action_values), size=n)
        t0 = int(rng.integers(0, 40))
        out = []
        for prune in (True, False):
            plan = start.copy()
            got = improve_plan(model_id(problem.model), s, plan, t0, n, problem.params(),
                               np.asarray(problem.action_values, dtype=np.float64),
                               *goal_arrays(problem), problem.is_angle, MIXED['acrobot'],
                               *ellipse, 10, 100, np.uint64(1000 + trial), prune)
            out.append((got, plan.tolist()))
        assert out[0] == out[1]
        entered += out[0][0] < FAR
    assert entered >= 4                   # most rounds had plans entering (pruned early)


def test_improving_never_worsens_and_reports_the_plan_it_keeps():
    problem = load_problem('acrobot')
    n = 150
    s = problem.initial_state.astype(np.float64)
    zero = int(np.argmin(np.abs(problem.action_values)))
    plan = np.full(n, zero, dtype=np.int64)
    before = score_alone(problem, plan, s, 0, EASY)
    args = (model_id(problem.model), s, plan, 0, n, problem.params(),
            np.asarray(problem.action_values, dtype=np.float64), *goal_arrays(problem),
            problem.is_angle, EASY, *BOX)
    got = improve_plan(*args, 6, 150, np.uint64(12345))
    assert got < before                              # a plan of zeros is easily bettered
    assert got == score_alone(problem, plan, s, 0, EASY)
    again = plan.copy()
    assert improve_plan(*args[:2], again, *args[3:], 6, 150, np.uint64(12345)) <= got
    # the draws are the key's: the same key, the same plan
    one = np.full(n, zero, dtype=np.int64)
    two = np.full(n, zero, dtype=np.int64)
    for p in (one, two):
        improve_plan(args[0], s, p, 0, n, *args[5:], 3, 50, np.uint64(7))
    assert one.tolist() == two.tolist()
    # the window: no action past it is ever redrawn
    window = np.full(n, zero, dtype=np.int64)
    improve_plan(args[0], s, window, 10, n, *args[5:], 4, 20, np.uint64(9))
    assert (window[:10] == zero).all() and (window[30:] == zero).all()


def test_on_the_exact_model_the_planned_episode_enters_when_planned_or_sooner(rng):
    problem = load_problem('acrobot')
    plant = Plant(problem, Disturbance(), 150)
    settings = ReplanSettings(replan_rounds=4, replan_every=5)
    plan = rng.integers(0, len(problem.action_values), size=150)
    planner = Replanner(problem, plan, settings, EASY)
    ep = planned_episode(planner, plant, (0, 0, 1, 0))
    planner.reset()
    promised = improve_plan(planner.model, problem.initial_state.astype(np.float64),
                            planner.plan, 0, 150, planner.p, planner.actions, *planner.goal,
                            problem.is_angle, EASY, *planner.ellipse, 4, 150,
                            np.uint64(episode_key(planner.key, 0, 0, 0)))
    assert promised < FAR
    assert 0 < ep['first_entry'] <= promised
    assert ep['steps'] == ep['first_entry']


def test_the_first_plan_is_the_policys_episode(rng):
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 30, rng)
    from sapga_ros.evaluation.evaluator import Evaluator
    ep = Evaluator(problem, EASY, 120).episode(policy)
    plan = first_plan(policy, 120, EASY)
    assert len(plan) == 120
    assert problem.action_values[plan[:ep.steps]].tolist() == ep.actions.tolist()
    assert (problem.action_values[plan[ep.steps:]] == 0.0).all()


def test_disturbed_planned_episodes_are_the_same_for_any_thread_count(rng):
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 20, rng)
    settings = ReplanSettings(replan_rounds=2, replan_every=10)
    one = planned_episodes(policy, EASY, 'field', 4, 3, settings, 1, 80, jobs=1)
    two = planned_episodes(policy, EASY, 'field', 4, 3, settings, 1, 80, jobs=2)
    assert one == two
    assert len({o['return'] for o in one}) > 1      # the draws differ between episodes
    # each episode starts where the engine's episode of the same key starts
    plant = Plant(problem, load_disturbance('field'), 80)
    assert not np.array_equal(plant.reset((3, 0, 1, 0)), problem.initial_state)


def test_a_planner_predicts_for_the_delay_given_else_the_files_own(rng):
    """``sapga eval --replan`` and the policy node plan for the same delay: the one given,
    else the one the policy file's selector is designed for."""
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 20, rng)
    designed = ahead(random_exemplars(problem, 20, rng), 2)
    assert (planner_delay(policy, 0), planner_delay(policy, 1)) == (0, 1)
    assert (planner_delay(designed, 0), planner_delay(designed, 3)) == (2, 3)
    for p, given, expected in ((policy, 0, 0), (designed, 0, 2), (designed, 1, 1)):
        p.meta = {'delta': 0.3}
        assert PlanningSelector(p, ReplanSettings(), given).planner.delay == expected


def test_a_hold_catch_is_designed_for_its_own_problem_and_delay():
    """The nominal design is kept per problem (every setting, not its name) and delay; a
    delay for which the LQR has no catch region is refused with one line."""
    problem = load_problem('acrobot_hold')
    wider = dataclasses.replace(problem, default_delta=problem.default_delta / 4,
                                goal_scale=tuple(2 * x for x in problem.goal_scale))
    assert HoldCatch(problem, 0).c != HoldCatch(wider, 0).c
    assert HoldCatch(wider, 0).c == HoldCatch(wider, 0).c
    with pytest.raises(SapgaError, match='no catch region for a delay of 100 steps'):
        HoldCatch(problem, 100)


def test_refusals():
    held_car = dataclasses.replace(load_problem('mountain_car'), ends_in_goal=False)
    with pytest.raises(SapgaError, match='hold task without a classical LQR'):
        Replanner(held_car, np.zeros(5, dtype=np.int64), ReplanSettings(), 0.02)
    for bad in ({'replan_rounds': 0}, {'replan_every': 0}, {'replan_window': 0},
                {'replan_seed': -1}, {'replan_fit': 1.5}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            ReplanSettings(**bad)


def test_a_state_near_the_start_after_a_while_starts_the_plan_again(rng):
    problem = load_problem('acrobot')
    plan = rng.integers(0, len(problem.action_values), size=100)
    planner = Replanner(problem, plan, ReplanSettings(replan_rounds=1, replan_every=1000), 0.02)
    s0 = problem.initial_state
    near = s0 + np.array([0.035, -0.035, 0.14, -0.3])   # START_TOL of each range
    far = s0 + np.array([0.0, 0.0, 0.16, 0.0])
    for t in range(RESTART_AFTER):
        planner.act(near)                      # early in the plan: no restart
    assert planner.t == RESTART_AFTER
    planner.act(far)
    assert planner.t == RESTART_AFTER + 1      # not a start
    wrapped = near.copy()
    wrapped[1] += 2 * np.pi                    # the same angle, a turn on
    planner.plan[:] = (planner.plan + 1) % 3
    first = planner.act(wrapped)
    assert planner.t == 1                      # started again, from the first plan:
    fresh = Replanner(problem, plan, planner.settings, 0.02)
    assert fresh.act(wrapped) == first and fresh.plan.tolist() == planner.plan.tolist()
    late = Replanner(problem, plan, planner.settings, 0.02, delay=2)
    for t in range(RESTART_AFTER):
        late.act(far)
    assert late.memory[0].tolist() != [0.0, 0.0]
    late.act(near)
    assert late.t == 1 and late.memory[0, 0] == 0.0   # the commands in flight forgotten


def test_a_hold_tasks_planner_hands_over_to_the_lqr_and_holds():
    """A hold task (acrobot_hold) re-planned from the classical controller's own episode:
    undisturbed, the planner aims at the LQR's region and the LQR, once there, holds the
    pendulum to the end; under field, its episodes are the same for any thread count and
    carry the hold measures (the return with a bonus for every step held)."""
    problem = load_problem('acrobot_hold')
    policy = classical_policy(problem)
    settings = ReplanSettings(replan_rounds=1, replan_every=10)
    (ep,) = planned_episodes(policy, 0.02, 'none', 1, 0, settings)
    assert ep['steps'] == problem.n_step and ep['first_entry'] > 0
    held = hold_measures(ep['first_entry'], ep['held'], ep['steps'], ep['contacts'])
    assert held['hold_fraction'] >= 0.9
    planner = Replanner(problem, first_plan(policy, problem.n_step, 0.02), settings, 0.02)
    assert planner.ellipse[1] == planner.catch.aim < planner.catch.c
    fit = ReplanSettings(replan_rounds=1, replan_every=10, replan_fit=0.05)
    one = planned_episodes(policy, 0.02, 'field', 2, 4, fit, 1, 300, jobs=1)
    assert one == planned_episodes(policy, 0.02, 'field', 2, 4, fit, 1, 300, jobs=2)
    assert all(o['steps'] == 300 for o in one)
