"""The physical-limit search (sapga_ros/analysis/limit.py): exhaustive when the beam holds
every sequence, its answer replays through the model, deterministic in its seed; the
replay (sapga_ros/analysis/limit_replay.py) scores a sequence under every goal reading and
counts its rail contacts; the committed sequences of docs/limits replay to their numbers."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from sapga_ros.analysis.limit import beam_limit, with_goal_scale
from sim_nodes.goal import delta_of
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem

LIMITS = Path(__file__).parents[1] / 'docs' / 'limits'


def brute_force(problem, depth):
    """The smallest delta(s) over every state of every action sequence of ``depth`` steps."""
    step = model_module(problem.model).mdp_step
    best = (delta_of(problem, problem.initial_state), 0)
    for seq in itertools.product(problem.actions, repeat=depth):
        s = problem.initial_state.copy()
        for t, a in enumerate(seq, 1):
            step(s, a, problem.params())
            best = min(best, (delta_of(problem, s), t))
    return best


def test_a_beam_wide_enough_for_every_sequence_is_exhaustive():
    """With width >= 3^depth and one child per cell kept, nothing is pruned: the search
    finds the exact minimum over all sequences."""
    problem = load_problem('pdip')
    depth = 6
    limit = beam_limit(problem, n_step=depth, width=3 ** depth, cells=1000, per_cell=1)
    want, step = brute_force(problem, depth)
    assert limit.delta == want and limit.step == step
    assert len(limit.actions) == limit.step


def test_the_search_is_seeded_and_its_sequence_replays():
    """Same seed, same answer; the action sequence reaches the reported delta (replayed by
    the search itself, and again here)."""
    problem = load_problem('acrobot')
    a = beam_limit(problem, n_step=80, width=500, cells=32, seed=3)
    b = beam_limit(problem, n_step=80, width=500, cells=32, seed=3)
    assert a == b
    s = problem.initial_state.copy()
    for action in a.actions:
        model_module(problem.model).mdp_step(s, action, problem.params())
    assert delta_of(problem, s) == a.delta


def test_a_wider_goal_box_never_makes_the_limit_larger():
    """|v| <= 32 delta contains |v| <= 16 delta: the same sequences reach a delta no larger."""
    problem = load_problem('pdip')
    wide = with_goal_scale(problem, {'v': 32.0})
    assert wide.goal_scale[1] == 32.0
    s = np.array([0.1, 0.5, 1.6, 1.5, 0.2, -0.1])
    assert delta_of(wide, s) <= delta_of(problem, s)


def test_a_replay_scores_the_searchs_sequence_under_every_goal_reading():
    """The sequence a search found replays to the search's delta and step under the reading
    it was searched under; under the wider |v| <= 32 delta box it is no larger."""
    from sapga_ros.analysis.limit_replay import replay
    problem = load_problem('pdip')
    found = beam_limit(problem, n_step=60, width=400, cells=16, seed=1)
    scores = {r.reading: r for r in replay(problem, found.actions)}
    assert set(scores) == {'printed', 'alternative'}
    assert (scores['printed'].delta, scores['printed'].step) == (found.delta, found.step)
    assert scores['alternative'].delta <= found.delta
    assert [r.reading for r in replay(load_problem('acrobot'), found.actions[:5])] == \
        ['printed']


def test_rail_contacts_are_the_steps_that_stopped_the_cart_at_the_rail():
    """Pushing one way drives the cart into the rail: every contact step counted leaves the
    cart at the rail end at rest (the free brake), no other step does; no force, no
    contact."""
    from sapga_ros.analysis.limit_replay import replay
    problem = load_problem('pdip')
    x_max = 2.5                                   # msg_configs/pdip.yaml: rail end
    push = [40.0] * 40
    s, at_rail = problem.initial_state.copy(), []
    for t, a in enumerate(push, 1):
        model_module(problem.model).mdp_step(s, a, problem.params())
        if abs(s[0]) == x_max and s[1] == 0.0:
            at_rail.append(t)
    last = max(replay(problem, push), key=lambda r: r.step)
    assert at_rail and last.contact_steps == tuple(t for t in at_rail if t <= last.step)
    assert all(r.rail_contacts == 0 for r in replay(problem, [0.0] * 40))


def _refuse(name: str):
    raise ValueError(f'{name} is not strict JSON')


def test_the_committed_limit_sequences_replay_to_their_numbers():
    """docs/limits/*.json (the sequences docs/reproduction.md reports) are strict JSON and
    each replays to the delta and step it records under the reading it was searched under."""
    import json
    from pathlib import Path

    from sapga_ros.analysis.limit_file import read_limit
    from sapga_ros.analysis.limit_replay import replay
    files = sorted((Path(__file__).parents[1] / 'docs' / 'limits').glob('*.json'))
    assert {p.name for p in files} >= {'acrobot.json', 'pdip.json', 'pdip-alternative.json'}
    for path in files:
        json.loads(path.read_text(), parse_constant=_refuse)   # no NaN or Infinity
        doc = read_limit(path)
        reading = 'alternative' if doc['alternative_goal'] else 'printed'
        got = {r.reading: r for r in replay(load_problem(doc['problem']), doc['actions'])}
        assert (got[reading].delta, got[reading].step) == (doc['delta'], doc['step']), path


def _acrobot(**changes) -> dict:
    return {**json.loads((LIMITS / 'acrobot.json').read_text()), **changes}


# Limit files that do not fit their problem (acrobot: actions -2, 0, 2; 400 steps an
# episode; 4 state coordinates; no alternative goal reading).
MISFITS = {
    'action outside the set': (_acrobot(actions=[2.0] * 399 + [7.0]), 'actions[399]'),
    'extreme action': (_acrobot(actions=[1e308] * 400), 'actions[0]'),
    'between two actions': (_acrobot(actions=[1.0] * 400), 'actions[0]'),
    'more steps than an episode': (_acrobot(actions=[0.0] * 401, step=401), 'step'),
    'goal scale of another problem': (_acrobot(goal_scale=[1.0] * 6), 'goal_scale'),
    'negative goal scale': (_acrobot(goal_scale=[-1.0] * 4), 'goal_scale[0]'),
    'alternative goal it has not': (_acrobot(alternative_goal=True), 'alternative_goal'),
    'extreme delta': (_acrobot(delta=1e308), 'delta'),
    'unknown problem': (_acrobot(problem='nope'), "problem: unknown problem 'nope'"),
}


@pytest.mark.parametrize('misfit', MISFITS)
def test_a_limit_file_that_does_not_fit_its_problem_is_one_line(tmp_path, misfit):
    from process_helpers import sapga_in_process
    doc, word = MISFITS[misfit]
    path = tmp_path / 'limit.json'
    path.write_text(json.dumps(doc))
    done = sapga_in_process(['limit', '--replay', str(path)])
    assert done.returncode == 2 and done.stdout == '', done.stdout
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and f'{path}: {word}' in lines[0], done.stderr


def test_a_limit_file_that_fits_replays(tmp_path):
    """The committed file, as it is and with the other actions of the set, replays."""
    from process_helpers import sapga_in_process
    path = tmp_path / 'limit.json'
    path.write_text(json.dumps(_acrobot(actions=[-2.0, 0, 2] * 133 + [0], delta=None)))
    done = sapga_in_process(['limit', '--replay', str(path)])
    assert done.returncode == 0 and 'printed' in done.stdout, done.stderr
