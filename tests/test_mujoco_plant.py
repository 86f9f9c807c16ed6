"""The MuJoCo plant (sim_nodes/mujoco_plant.py) against the compiled kernels.

How closely they agree, from 4 start states (the initial state and 3 spread by U(-0.3, 0.3)
per coordinate) under random actions:

* acrobot: MuJoCo's RK4 integrates the same equations as the kernel's RK4, so the two agree
  to about 1e-14 rad over 40 MDP steps (2 s) of swinging; asserted: 1e-9.  They part later,
  once the kernel clips a velocity (MuJoCo has no clip) and chaos grows the round-off.
* pdip, pdip_single: the kernel integrates with semi-implicit Euler, MuJoCo with RK4 (an
  O(dt) difference per step), so they agree to about 0.05 over 10 MDP steps (0.5 s; largest
  difference of any coordinate, angles on the circle); asserted: 0.1.  Over 2 s they differ
  by radians: the poles are chaotic, and the rail differs (the kernel stops the cart and
  zeroes its velocity, MuJoCo's joint limit is a soft constraint).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim_nodes.errors import ConfigError
from sim_nodes.models import model_module
from sim_nodes.mujoco_plant import MujocoPlant, mapping
from sim_nodes.problem import load_problem

pytest.importorskip('mujoco')


def difference(a: np.ndarray, b: np.ndarray, is_angle: np.ndarray) -> float:
    d = np.abs(a - b)
    d = np.where(is_angle, np.minimum(d % (2 * math.pi), 2 * math.pi - d % (2 * math.pi)), d)
    return float(d.max())


def starts(problem, rng):
    s0 = problem.initial_state
    yield s0.copy()
    for _ in range(3):
        s = s0 + rng.uniform(-0.3, 0.3, s0.shape)
        if problem.name == 'pdip_single':       # one pole: both coordinates equal
            s[3], s[5] = s[2], s[4]
        yield s


@pytest.mark.parametrize('name, steps, tolerance', [
    ('acrobot', 40, 1e-9), ('pdip', 10, 0.1), ('pdip_single', 10, 0.1)])
def test_mujoco_agrees_with_the_kernel_over_short_horizons(name, steps, tolerance):
    problem = load_problem(name)
    plant = MujocoPlant(problem)
    kernel = model_module(problem.model).mdp_step
    p = problem.params()
    rng = np.random.default_rng(0)
    worst = 0.0
    for s in starts(problem, rng):
        plant.reset(s)
        assert difference(plant.problem_state(), s, problem.is_angle) < 1e-12
        for a in rng.choice(problem.action_values, steps):
            r_kernel = kernel(s, a, p)
            plant.step(plant.problem_effort(a))
            sm = plant.problem_state()
            worst = max(worst, difference(s, sm, problem.is_angle))
            assert abs(plant.reward(sm) - r_kernel) < 10 * tolerance
    assert worst < tolerance, f'{name}: differs by {worst} within {steps} steps'


def test_the_robot_speaks_its_own_convention():
    """MuJoCo's joint names, zero hanging down, and efforts in its own direction."""
    acro = MujocoPlant(load_problem('acrobot'))
    assert acro.joint_names == ('shoulder', 'elbow') and acro.actuator_joints == ('elbow',)
    acro.reset(load_problem('acrobot').initial_state)      # hanging down: MuJoCo's zero
    assert np.allclose(acro.positions, 0.0) and np.allclose(acro.velocities, 0.0)
    acro.step(np.array([1.0]))                 # positive elbow effort: elbow angle grows,
    assert acro.positions[1] > 0 and acro.problem_state()[1] > math.pi   # theta2 falls
    single = MujocoPlant(load_problem('pdip_single'))
    assert single.joint_names == ('slider', 'hinge')
    assert MujocoPlant(load_problem('pdip')).joint_names == ('slider', 'hinge1', 'hinge2')
    assert mapping(load_problem('pdip_single'))['pole2'].robot_joint == 'hinge'


def test_the_rail_is_a_joint_limit_and_counts_as_a_contact():
    problem = load_problem('pdip')
    plant = MujocoPlant(problem)
    plant.reset(problem.initial_state)
    rewards = []
    for _ in range(60):
        plant.step(40.0)
        rewards.append(plant.reward(plant.problem_state()))
    assert plant.contact and min(rewards) < -100
    assert plant.positions[0] < problem.physics['x_max'] + 0.1   # held near the rail end


def test_a_problem_without_a_mujoco_model_is_refused_in_one_line():
    with pytest.raises(ConfigError, match='no MuJoCo model of .mountain_car'):
        MujocoPlant(load_problem('mountain_car'))


def drawn_physics(problem, episode):
    """The packed physics of ``field``'s model error for one episode (masses and lengths
    x U(0.95, 1.05))."""
    from sim_nodes.disturbance import Plant, load_disturbance
    plant = Plant(problem, load_disturbance('field'))
    plant.reset((0, 0, 1, episode))
    return plant.params


@pytest.mark.parametrize('name', ['acrobot', 'pdip'])
def test_a_robot_with_model_error_is_the_kernel_of_its_drawn_physics(name):
    """Rebuilt with an episode's drawn masses and lengths, the robot keeps its joints and
    agrees with the kernel stepped with those parameters as closely as the nominal robot
    agrees with the nominal kernel, and visibly not with the nominal kernel."""
    problem = load_problem(name)
    steps, tolerance = (40, 1e-9) if name == 'acrobot' else (10, 0.1)
    plant = MujocoPlant(problem)
    joints = plant.joint_names
    kernel = model_module(problem.model).mdp_step
    p = drawn_physics(problem, 3)
    assert not np.array_equal(p, problem.params())
    plant.set_physics(p)
    assert plant.joint_names == joints and np.array_equal(plant.params, p)
    rng = np.random.default_rng(1)
    s = problem.initial_state.copy()
    nominal = s.copy()
    plant.reset(s)
    for a in rng.choice(problem.action_values, steps):
        kernel(s, a, p)
        kernel(nominal, a, problem.params())
        plant.step(plant.problem_effort(a))
    assert difference(s, plant.problem_state(), problem.is_angle) < tolerance
    if name == 'acrobot':
        assert difference(nominal, plant.problem_state(), problem.is_angle) > 1e-3
    plant.set_physics(problem.params())                   # back to the nominal robot
    assert plant.xml == MujocoPlant(problem).xml


def test_a_push_on_the_problem_state_reaches_the_robot():
    """The simulator pushes its problem state; the MuJoCo engine writes the pushed
    coordinate into the robot before stepping: the kernel's step from the pushed state."""
    from sim_nodes.ros.mujoco_engine import MujocoEngine
    problem = load_problem('acrobot')
    engine = MujocoEngine(problem)
    kernel = model_module(problem.model).mdp_step
    p = problem.params()
    s = problem.initial_state.copy()
    engine.reset(s, p)
    for a in (2.0, -2.0, 2.0):
        engine.mdp_step(s, a, p)
    pushed = s.copy()
    pushed[2] += 0.3                                       # theta1 rate
    expected, unpushed = pushed.copy(), s.copy()
    kernel(expected, 0.0, p)
    kernel(unpushed, 0.0, p)
    engine.mdp_step(pushed, 0.0, p)
    assert difference(pushed, expected, problem.is_angle) < 1e-9
    assert difference(pushed, unpushed, problem.is_angle) > 1e-3


def test_a_spread_start_of_the_single_pole_robot_is_not_rewritten_by_the_first_step():
    """The single-pole cart's two pole angles name one hinge: a spread start puts the hinge
    where the second says, and the first step starts there (nothing is pushed)."""
    from sim_nodes.ros.mujoco_engine import MujocoEngine
    problem = load_problem('pdip_single')
    engine, alone = MujocoEngine(problem), MujocoPlant(problem)
    s = problem.initial_state + np.array([0.01, 0.02, -0.03, 0.04, 0.05, -0.06])
    engine.reset(s.copy(), problem.params())
    alone.reset(s)
    engine.mdp_step(s, 5.0, problem.params())
    alone.step(alone.problem_effort(5.0))
    assert np.array_equal(engine.plant.positions, alone.positions)
    assert np.array_equal(engine.plant.velocities, alone.velocities)


def test_the_published_joints_carry_the_sensor_noise_and_only_it():
    """What the MuJoCo robot reports is its joints plus the noise of the state seen (in its
    own convention), and its joints bit for bit when nothing is added."""
    from sim_nodes.ros.mujoco_engine import MujocoEngine
    problem = load_problem('acrobot')
    engine = MujocoEngine(problem)
    s = problem.initial_state.copy()
    engine.reset(s, problem.params())
    for a in (2.0, 2.0, -2.0):
        engine.mdp_step(s, a, problem.params())
    msg = engine.fill(engine.new_msg(), s.copy(), 0.0, 0)
    assert np.array_equal(msg.position, engine.plant.positions)
    assert np.array_equal(msg.velocity, engine.plant.velocities)
    noise = np.array([0.003, -0.002, 0.001, 0.004])
    seen = s + noise
    seen[:2] %= 2 * math.pi
    msg = engine.fill(engine.new_msg(), seen, 0.0, 0)
    robot = MujocoPlant(problem)                 # the noisy joints mapped back
    robot.reset(s)
    robot.data.qpos[:] = msg.position
    robot.data.qvel[:] = msg.velocity
    assert difference(robot.problem_state(), seen, problem.is_angle) < 1e-12
