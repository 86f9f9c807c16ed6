"""Mountain car (SPEC 2.3): a problem added as one YAML file plus one kernel, and the
policy map of the paper's Figure 5."""
import math

import numpy as np

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.viz.exemplar_plot import plot_exemplars, policy_map
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes import goal
from sim_nodes.models.mountain_car import mdp_step
from sim_nodes.problem import load_problem


def test_left_wall_stops_the_car_and_right_end_is_the_goal():
    """Driving left ends at x = -1.2 with v = 0; x never passes 0.5, where delta is 0."""
    pr = load_problem('mountain_car')
    p = pr.params()
    s = np.array([-1.15, -0.07])
    mdp_step(s, -1.0, p)
    assert s[0] == -1.2 and s[1] == 0.0
    s = np.array([0.49, 0.07])
    assert mdp_step(s, 1.0, p) == -1.0
    assert s[0] == 0.5 and goal.delta_of(pr, s) == 0.0
    assert math.isclose(goal.delta_of(pr, [-1.2, 0.0]), 1.0)


def test_energy_pumping_policy_reaches_the_goal_and_constant_push_does_not():
    """Pushing along the velocity (the textbook solution) climbs out of the valley within
    N_step; pushing right only does not (the car is under-powered)."""
    pr = load_problem('mountain_car')
    ev = Evaluator(pr, 0.0)
    pump = ExemplarPolicy(pr, [[0.0, -0.001], [0.0, 0.001]], [0, 1])
    right = ExemplarPolicy(pr, [[0.0, 0.0]], [1])
    ep = ev.episode(pump)
    assert ep.reached and ep.ret == -ep.steps and ep.steps < 200
    assert not ev.episode(right).reached


def test_policy_map_is_the_nearest_exemplar_action_everywhere(tmp_path):
    """The map's action at each grid point is the action of the nearest exemplar by the
    normalised distance, and the figure is written."""
    pr = load_problem('mountain_car')
    pol = ExemplarPolicy(pr, [[-0.5, -0.02], [0.2, 0.03], [-1.0, 0.05]], [0, 1, 1])
    xs, ys, grid = policy_map(pol, resolution=40)
    for i in range(0, 40, 7):
        for j in range(0, 40, 7):
            d = np.hypot((pol.states[:, 0] - xs[j]) / 1.7, (pol.states[:, 1] - ys[i]) / 0.14)
            assert grid[i, j] == pol.action_values[np.argmin(d)]
    out = tmp_path / 'map.png'
    plot_exemplars(pol, Evaluator(pr, 0.0).episode(pol), np.ones(3), str(out))
    assert out.stat().st_size > 10_000
