"""The five exemplar styles (SPEC 3.1): each selector against an independent NumPy reading of
the spec, batch == traced episode == one-state-at-a-time selection, the operators on every
style's records, and the policy file form of every style."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sapga_ros.errors import PolicyFileError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.policies.runnable import policy_from_json
from sapga_ros.policies.styles import STYLES
from sapga_ros.optim.operators import random_exemplars, refresh, uniform_crossover
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem

STYLE_NAMES = list(STYLES)


@pytest.fixture(params=['acrobot', 'pdip', 'mountain_car'])
def problem(request):
    return load_problem(request.param)


def random_style_policies(problem, style, count, seed=0, size=40):
    rng = np.random.default_rng(seed)
    return [random_exemplars(problem, size + k % 7, rng, style) for k in range(count)]


# --- an independent reading of SPEC 3.1, in plain NumPy -----------------------------------

def norm(problem, s):
    u = np.asarray(s, dtype=float) / problem.ranges
    u[..., problem.is_angle] = np.mod(u[..., problem.is_angle], 1.0)
    return u


def dist(problem, a, b):
    """Normalised Euclidean distance, circular on angles (a: (D,), b: (D,) or (L, D))."""
    d = np.abs(norm(problem, a) - norm(problem, b))
    d[..., problem.is_angle] = np.minimum(d[..., problem.is_angle],
                                          1.0 - d[..., problem.is_angle])
    return np.sqrt((d ** 2).sum(axis=-1))


def next_state(problem, s, action):
    s = np.array(s, dtype=float)
    model_module(problem.model).mdp_step(s, action, problem.params())
    return s


def spec_select(problem, policy, s, progress):
    """(action value, progress) as SPEC 3.1 words it."""
    actions = problem.action_values
    style = policy.style
    if style == 'state-action':
        return actions[policy.actions[np.argmin(dist(problem, s, policy.states))]], progress
    if style == 'state-action-value':
        d = dist(problem, s, policy.states)
        q = [policy.values[np.flatnonzero(policy.actions == a)[
            np.argmin(d[policy.actions == a])]] if np.any(policy.actions == a) else -np.inf
            for a in range(len(actions))]
        return actions[int(np.argmax(q))], progress
    nxt = [next_state(problem, s, a) for a in actions]
    if style == 'via-point':
        r = problem.via_point_radius
        while progress < len(policy) and dist(problem, s, policy.states[progress]) <= r:
            progress += 1
        target = problem.best_state if progress >= len(policy) else policy.states[progress]
        score = [-dist(problem, c, target) for c in nxt]
    elif style == 'state-value':
        score = [policy.values[np.argmin(dist(problem, c, policy.states))] for c in nxt]
    else:
        score = [dist(problem, c, policy.states2).min() - dist(problem, c, policy.states).min()
                 for c in nxt]
    return actions[int(np.argmax(score))], progress


# --- tests ---------------------------------------------------------------------------------

@pytest.mark.parametrize('style', STYLE_NAMES)
def test_selector_follows_the_spec_on_every_step(problem, style):
    """Along the traced episode, each action is the one SPEC 3.1's rule picks (NumPy)."""
    policy = random_style_policies(problem, style, 1, seed=3)[0]
    ep = Evaluator(problem, 0.0, n_step=60).episode(policy)
    progress = 0
    for t in range(ep.steps):
        want, progress = spec_select(problem, policy, ep.states[t], progress)
        assert ep.actions[t] == want, f'step {t}'


@pytest.mark.parametrize('style', STYLE_NAMES)
def test_batch_traced_and_single_state_selection_agree_exactly(problem, style):
    """evaluate() of a batch, episode() and StateSelector driving the model give the same
    returns, delta*, steps and referral marks, bit for bit."""
    policies = random_style_policies(problem, style, 11, seed=5)
    ev = Evaluator(problem, 0.2)
    batch = ev.evaluate(policies)
    step = model_module(problem.model).mdp_step
    for k, policy in enumerate(policies):
        ep = ev.episode(policy)
        assert (ep.ret, ep.steps, ep.delta_star, ep.reached) == (
            batch.returns[k], batch.steps[k], batch.delta_star[k], batch.reached[k])
        assert np.array_equal(ep.used, batch.used[k])
        selector = StateSelector(policy)
        s = problem.initial_state.copy()
        total = 0.0
        for t in range(ep.steps):
            j, action = selector.select(s)
            assert (j, action) == (ep.exemplars[t], ep.actions[t])
            total += step(s, action, problem.params())
            assert np.array_equal(s, ep.states[t + 1])
        assert total == ep.ret
        assert np.array_equal(selector.used, ep.used)


@pytest.mark.parametrize('style', STYLE_NAMES)
def test_referral_marks_are_the_exemplars_the_rule_looked_at(style):
    """Pruning the exemplars never referred to leaves the episode unchanged."""
    problem = load_problem('acrobot')
    for policy in random_style_policies(problem, style, 4, seed=11):
        ev = Evaluator(problem, 0.0, n_step=120)
        ep = ev.episode(policy)
        assert ep.used.any()
        pruned = ev.episode(policy.subset(ep.used))
        assert np.array_equal(pruned.states, ep.states) and pruned.ret == ep.ret


def test_via_point_targets_advance_in_order():
    """A via-point list starting at the initial state passes it at once; an unreachable one
    is targeted for the whole episode (the reported index)."""
    problem = load_problem('acrobot')
    far = problem.initial_state + np.array([math.pi, 0, 0, 0])
    policy = random_exemplars(problem, 2, np.random.default_rng(0), 'via-point')
    policy.states[:] = [problem.initial_state, far]
    ep = Evaluator(problem, 0.0, n_step=30).episode(policy)
    assert set(ep.exemplars) == {1}
    assert list(ep.used) == [False, True]


@pytest.mark.parametrize('style', STYLE_NAMES)
def test_random_exemplars_draw_every_field_of_the_style(style):
    """States within bounds, actions over the set, values within an episode's return range."""
    problem = load_problem('pdip')
    fresh = random_exemplars(problem, 3000, np.random.default_rng(2), style)
    assert np.all(fresh.states >= problem.low) and np.all(fresh.states < problem.high)
    spec = STYLES[style]
    if spec.uses('state2'):
        assert fresh.states2.shape == fresh.states.shape
        assert np.all(fresh.states2 >= problem.low) and np.all(fresh.states2 < problem.high)
    if spec.uses('action'):
        assert set(fresh.actions) == set(range(len(problem.actions)))
    if spec.uses('value'):
        low, high = problem.return_range
        assert low == 400 * -105 and high == -1
        assert fresh.values.min() >= low and fresh.values.max() <= high
        assert fresh.values.std() > 0.2 * (high - low)


@pytest.mark.parametrize('style', STYLE_NAMES)
def test_crossover_and_refresh_act_on_whole_records(style):
    """A child holds only whole records of its parents (or, repaired, fresh ones); refresh
    re-draws only exemplars that were not referred to."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(4)
    p1, p2 = random_style_policies(problem, style, 2, seed=9, size=60)
    parents = {r.tobytes() for p in (p1, p2) for r in p.records()}
    for _ in range(20):
        child, repaired = uniform_crossover(p1, p2, rng, 50, 100)
        assert child.style == style and 50 <= len(child) <= 100
        rows = [r.tobytes() for r in child.records()]
        assert len(set(rows)) == len(rows)
        if not repaired:
            assert set(rows) <= parents
    used = rng.random(len(p1)) < 0.5
    clone, count = refresh(p1, used, np.random.default_rng(1), rate=(1.0, 1.0))
    assert count == int((~used).sum())
    assert np.array_equal(clone.records()[used], p1.records()[used])
    assert not np.any(np.all(clone.records()[~used] == p1.records()[~used], axis=1))


@pytest.mark.parametrize('style', STYLE_NAMES)
def test_policy_file_round_trip_of_every_style(style):
    """to_json -> policy_from_json gives the same records; the file names the style's keys."""
    problem = load_problem('pdip')
    policy = random_style_policies(problem, style, 1, seed=1)[0]
    text = policy.to_json()
    doc = json.loads(text)
    assert doc['style'] == style
    assert set(doc['exemplars'][0]) == set(STYLES[style].keys.values())
    back = policy_from_json(text, 'pdip')
    assert back.style == style
    assert np.array_equal(back.records(), policy.records())


@pytest.mark.parametrize('style,key,bad,message', [
    ('state-value', 'value', 'NaN', 'exemplars[0].value'),
    ('state-value', 'value', '"high"', 'exemplars[0].value: expected a number'),
    ('state-state', 'worse', '[1, 2]', 'exemplars[0].worse: expected 4 numbers'),
    ('state-action-value', 'action', '1.5', 'exemplars[0].action: 1.5 is not one of'),
])
def test_bad_exemplar_fields_are_named(style, key, bad, message):
    """A wrong field of a style's exemplar is refused with the field's name."""
    problem = load_problem('acrobot')
    doc = json.loads(random_style_policies(problem, style, 1)[0].to_json())
    doc['exemplars'][0][key] = '@'
    text = json.dumps(doc).replace('"@"', bad)
    with pytest.raises(PolicyFileError, match=message.replace('[', r'\[').replace(']', r'\]')):
        policy_from_json(text)


def test_missing_style_key_and_unknown_style_are_refused():
    """An exemplar lacking one of its style's keys, or an unknown style, is one clear error."""
    problem = load_problem('acrobot')
    doc = json.loads(random_style_policies(problem, 'state-state', 1)[0].to_json())
    del doc['exemplars'][2]['worse']
    with pytest.raises(PolicyFileError, match=r'exemplars\[2\]: expected an object with '
                                              r'"better", "worse"'):
        policy_from_json(json.dumps(doc))
    doc['style'] = 'telepathy'
    with pytest.raises(PolicyFileError, match='style:.*not supported'):
        policy_from_json(json.dumps(doc))
