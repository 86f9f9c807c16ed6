"""What a state looks like (sim_nodes/geometry.py): properties of the pictures, checked against
the models' own conventions (their docstrings and reward formulas), and the goal band."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim_nodes.geometry import (DRAWINGS, goal_band, goal_states, hill_height, picture,
                                track)
from sim_nodes.goal import delta_of
from sim_nodes.models import MODELS
from sim_nodes.problem import load_problem, problem_names


@pytest.fixture(scope='module')
def rng():
    return np.random.default_rng(3)


def random_states(problem, rng, n: int = 50) -> np.ndarray:
    return rng.uniform(problem.low, problem.high, (n, problem.dim))


def length(seg) -> float:
    (x0, z0), (x1, z1) = seg
    return math.hypot(x1 - x0, z1 - z0)


def test_the_models_of_the_package_are_drawn():
    """Every drawing is of a model of sim_nodes/models, and the package's own models are all
    drawn (a new model without an entry draws nothing, which is allowed)."""
    assert set(DRAWINGS) <= set(MODELS)
    assert {'acrobot', 'mountain_car', 'pdip', 'pendulum'} <= set(DRAWINGS)


def test_acrobot_upright_puts_the_tip_at_l1_plus_2lc2_and_hanging_below(rng):
    """Upright (pi/2, 0): the tip at (0, l1 + 2 lc2); hanging (3pi/2, 0): at (0, -(...))."""
    p = load_problem('acrobot')
    reach = p.physics['l1'] + 2 * p.physics['lc2']
    assert picture(p, p.best_state).tip == pytest.approx((0.0, reach), abs=1e-12)
    assert picture(p, p.initial_state).tip == pytest.approx((0.0, -reach), abs=1e-12)
    for s in random_states(p, rng):
        pic = picture(p, s)
        assert pic.links[0][0] == (0.0, 0.0) and pic.links[0][1] == pic.links[1][0]
        assert length(pic.links[0]) == pytest.approx(p.physics['l1'])
        assert length(pic.links[1]) == pytest.approx(2 * p.physics['lc2'])


def test_acrobot_tip_height_is_the_reward_plus_3(rng):
    """The model's reward sin(theta1) + sin(theta1 + theta2) - 3 is the tip height - 3 for
    unit links: the picture agrees with the dynamics' own angle convention."""
    p = load_problem('acrobot')
    assert p.physics['l1'] == 1.0 and 2 * p.physics['lc2'] == 1.0
    for s in random_states(p, rng):
        reward = math.sin(s[0]) + math.sin(s[0] + s[1]) - 3
        assert picture(p, s).tip[1] - 3 == pytest.approx(reward, abs=1e-12)


@pytest.mark.parametrize('name', ['pdip', 'pdip_single'])
def test_pdip_cart_sits_at_x_on_the_rail_and_the_poles_have_their_lengths(rng, name):
    """The cart (and both poles' pivots) at (x, 0); pole i has length l_i at angle theta_i;
    the rail spans [-x_max, x_max]; up is pi/2."""
    p = load_problem(name)
    ph = p.physics
    assert track(p) == ((-ph['x_max'], 0.0), (ph['x_max'], 0.0))
    for s in random_states(p, rng):
        pic = picture(p, s)
        assert pic.body == (s[0], 0.0)
        for (pivot, tip), key, angle in zip(pic.links, ('l1', 'l2'), (s[2], s[3])):
            assert pivot == (s[0], 0.0)
            assert length((pivot, tip)) == pytest.approx(ph[key])
            assert math.atan2(tip[1], tip[0] - s[0]) % (2 * math.pi) == pytest.approx(
                angle % (2 * math.pi))
    up = picture(p, p.best_state)
    assert np.allclose([tip for _, tip in up.links], [(0.0, ph['l1']), (0.0, ph['l2'])])


def test_pendulum_rod_has_length_l_and_hangs_down_at_the_start():
    p = load_problem('pendulum')
    assert picture(p, p.initial_state).tip == pytest.approx((0.0, -p.physics['l']), abs=1e-12)
    assert picture(p, p.best_state).tip == pytest.approx((0.0, p.physics['l']), abs=1e-12)


def test_mountain_car_rides_on_its_hill_whose_slope_is_the_gravity_term(rng):
    """The car sits on z = sin(3x)/3, the hill whose slope cos(3x) the model's gravity
    term uses; the hill spans [x_min, x_max]."""
    p = load_problem('mountain_car')
    hill = track(p)
    assert hill[0][0] == p.physics['x_min'] and hill[-1][0] == p.physics['x_max']
    assert all(z == hill_height(x) for x, z in hill)
    for s in random_states(p, rng):
        assert picture(p, s).body == (s[0], hill_height(s[0]))
    h = 1e-6
    assert (hill_height(0.3 + h) - hill_height(0.3 - h)) / (2 * h) == pytest.approx(
        math.cos(0.9), rel=1e-6)


@pytest.mark.parametrize('name', problem_names())
def test_goal_states_are_the_best_state_and_the_edges_of_the_goal_band(name):
    """Every state goal_states draws lies in S_delta (delta(s) <= delta); the first is the
    best state; the edges sit at the band's bound of one position coordinate."""
    p = load_problem(name)
    delta = p.default_delta
    states = goal_states(p, delta)
    assert np.array_equal(states[0], p.best_state)
    half = goal_band(p, delta)
    for s in states[1:]:
        (i,) = np.flatnonzero(s != p.best_state)
        assert p.state[i].field == 'position'
        assert abs(s[i] - p.best_state[i]) == pytest.approx(half[i])
    assert all(delta_of(p, s) <= delta * (1 + 1e-9) for s in states)


def test_goal_band_takes_the_fixed_bound_and_caps_angles_at_pi():
    """PDIP x: the fixed |x| <= 2 whatever delta; angles: never more than the half circle."""
    p = load_problem('pdip')
    assert goal_band(p, 0.01)[0] == 2.0
    assert goal_band(p, 0.01)[2] == pytest.approx(2 * math.pi * 0.01)
    assert goal_band(p, 0.9)[2] == math.pi
    assert len(goal_states(p, 0.9)) == 3      # the angles' band is the whole circle
