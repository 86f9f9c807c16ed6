"""The one episode engine: every episode loop of the package computes what ``run_share``
computes.  The batch and the traced episode are the same loop (tests/test_styles.py); the
ROS simulator's stepping equals it (tests/test_sim_node.py, tests/test_styles_ros.py); here,
Q-learning's greedy episode equals the engine running the same greedy policy written as
state-action exemplars (one per tile centre: on a rectangular grid the nearest centre under
the normalised distance is the tile holding the state)."""
from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.qtable import QTable
from sim_nodes.problem import load_problem


def tile_centre_policy(table: QTable) -> ExemplarPolicy:
    """The greedy policy of ``table`` as exemplars at the tile centres (first-index ties)."""
    problem = table.problem
    idx, low, width, tiles = table.tiling
    assert list(idx) == list(range(problem.dim))
    states, actions = [], []
    for cell_digits in itertools.product(range(tiles), repeat=len(idx)):
        digits = np.array(cell_digits[::-1])       # cell = sum digit_i * tiles^i
        cell = int(sum(d * tiles ** i for i, d in enumerate(digits)))
        states.append(low + (digits + 0.5) * width)
        actions.append(int(np.argmax(table.q[cell])))
    return ExemplarPolicy(problem, np.array(states), np.array(actions))


def test_q_learning_greedy_episode_equals_the_engine():
    """Same states, actions, rewards, return, delta* and end, bit for bit (mountain car;
    19 tiles a side, so that the initial v = 0 lies inside a tile, not on a tile edge, where
    the tiling and the nearest centre may break the tie differently)."""
    problem = dataclasses.replace(load_problem('mountain_car'), ql_tiles_per_dim=19)
    rng = np.random.default_rng(8)
    tiles = problem.ql_tiles_per_dim
    for trial in range(8):
        q = rng.normal(size=(tiles ** problem.dim, len(problem.actions)))
        table = QTable(problem, q, np.ones(len(q), dtype=bool), {})
        greedy = table.episode(0.0)
        engine = Evaluator(problem, 0.0).episode(tile_centre_policy(table))
        assert np.array_equal(greedy.states, engine.states), trial
        assert np.array_equal(greedy.actions, engine.actions)
        assert np.array_equal(greedy.rewards, engine.rewards)
        assert (greedy.ret, greedy.steps, greedy.delta_star, greedy.reached) == (
            engine.ret, engine.steps, engine.delta_star, engine.reached)


def test_the_alternative_goal_reading_is_measured_beside_the_printed_one():
    """PDIP: the engine's delta* under |v| <= 32 delta is the minimum over the episode's
    states of that reading's delta(s), never above the printed box's delta*; problems
    without an alternative reading measure none."""
    from sapga_ros.analysis.limit import with_goal_scale
    from sapga_ros.optim.operators import random_exemplars
    from sim_nodes.goal import delta_of
    problem = load_problem('pdip')
    alt = with_goal_scale(problem, {'v': 32.0})
    assert problem.goal_alt_scale == alt.goal_scale
    policies = [random_exemplars(problem, 60, np.random.default_rng(k)) for k in range(6)]
    ev = Evaluator(problem, 0.05)
    batch = ev.evaluate(policies)
    for k, policy in enumerate(policies):
        ep = ev.episode(policy)
        want = min(delta_of(alt, s) for s in ep.states)
        assert batch.delta_star_alt[k] == want <= batch.delta_star[k]
    assert Evaluator(load_problem('acrobot')).evaluate(policies[:0]).delta_star_alt is None


def test_training_logs_both_goal_readings_on_the_pdip():
    """Every log row of a PDIP run (SAP-GA and Q-learning) carries delta* under the
    alternative reading, never above the printed box's and never rising; the acrobot's
    rows carry none."""
    from sapga_ros.training.loop import TrainConfig, train
    for problem, method in (('pdip', 'sapga'), ('pdip_single', 'ql')):
        rows = train(TrainConfig(problem=problem, method=method, steps=300_000, seed=1,
                                 jobs=1)).history
        alt = [r['delta_star_alt'] for r in rows]
        assert all(a <= r['delta_star'] for a, r in zip(alt, rows))
        assert alt == sorted(alt, reverse=True)
    rows = train(TrainConfig(problem='acrobot', steps=100_000, seed=1, jobs=1)).history
    assert 'delta_star_alt' not in rows[-1]


@pytest.mark.parametrize('disturbance', ['none', 'field', 'push'])
def test_state_action_loop_equals_the_general_loop_bit_for_bit(disturbance):
    """The engine's loop for state-action policies without a controller (the lanes'
    states normalised side by side, the nearest exemplar found directly) computes what the
    general loop computes through ``choose`` (forced here by a controller row of mode
    none): every result of every policy, and the traced episode, undisturbed and under
    draws (noise, latency, mismatch, pushes)."""
    from sapga_ros.optim.operators import random_exemplars
    from sim_nodes.disturbance import load_disturbance
    rng = np.random.default_rng(7)
    draws = load_disturbance(disturbance)
    keys = np.column_stack([np.full(37, 3), np.full(37, 1), np.arange(37), np.arange(37) % 4])
    for name, delta in (('acrobot', 0.0), ('acrobot', 0.4), ('pdip', 0.3), ('pdip_hold', None),
                        ('mountain_car', None)):
        problem = load_problem(name)
        policies = [random_exemplars(problem, int(rng.integers(1, 120)), rng, 'state-action')
                    for _ in range(37)]
        direct = Evaluator(problem, delta=delta, disturbance=draws)
        general = Evaluator(problem, delta=delta, disturbance=draws)
        general.catch = np.zeros(2)              # mode none: choose falls through to select
        assert general.controls(policies).shape == (37, 2)
        a, b = direct.evaluate(policies, keys), general.evaluate(policies, keys)
        for field in ('returns', 'steps', 'delta_star', 'reached', 'first_entry', 'held',
                      'contacts'):
            assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), (name, field)
        assert all(np.array_equal(u, v) for u, v in zip(a.used, b.used))
        if delta:                                # some episodes end in the goal
            assert a.reached.any() and not a.reached.all(), name
        if name == 'pdip_hold':                  # and some touch the end stop
            assert a.contacts.any()
        ea, eb = direct.episode(policies[5], tuple(keys[5])), \
            general.episode(policies[5], tuple(keys[5]))
        for field in ('states', 'actions', 'exemplars', 'rewards', 'used'):
            assert getattr(ea, field).tobytes() == getattr(eb, field).tobytes(), field
        assert (ea.ret, ea.steps, ea.delta_star, ea.reached, ea.first_entry, ea.held,
                ea.contacts) == (eb.ret, eb.steps, eb.delta_star, eb.reached, eb.first_entry,
                                 eb.held, eb.contacts)
        assert ea.ret == a.returns[5] and ea.steps == a.steps[5]
