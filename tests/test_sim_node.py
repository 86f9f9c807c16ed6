"""Simulator node (sim_nodes/ros/sim_node.py) over real Fast DDS: lockstep fidelity to the offline
evaluator, reset, bad commands, realtime mode and parameter validation."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from ros_helpers import PROBE_QOS, Probe, isolated_ros, run_lockstep
from sapga_ros.evaluation.evaluator import Evaluator
from sim_nodes.ros.common import JointStateLayout
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem
from sim_nodes.ros.sim_node import SimNode

TICK_NS = 50_000_000  # sim time per published new state of the pendulums: 0.05 s
PARAMS_DIR = Path(__file__).resolve().parents[1] / 'msg_configs' / 'params'


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


def random_policies(problem, count: int, seed: int = 0) -> list[ExemplarPolicy]:
    rng = np.random.default_rng(seed)
    return [ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (60, problem.dim)),
                           rng.integers(0, 3, 60)) for _ in range(count)]


@pytest.fixture(scope='module')
def acrobot_cases():
    """Two seeded random acrobot policies at delta 0.3: one reaches the goal, one does not."""
    problem = load_problem('acrobot')
    policies = random_policies(problem, 40)
    result = Evaluator(problem, 0.3).evaluate(policies)
    goal = policies[int(np.argmax(result.reached))]
    limit = policies[int(np.argmin(result.reached))]
    assert result.reached.any() and not result.reached.all()
    return problem, [goal, limit]


@pytest.mark.parametrize('case', [0, 1], ids=['goal', 'step_limit'])
def test_lockstep_acrobot_episode_equals_offline_evaluation(ros, acrobot_cases, case, tmp_path):
    """A lockstep acrobot episode through DDS equals Evaluator.episode bit for bit."""
    problem, policies = acrobot_cases
    policy = policies[case]
    ep = Evaluator(problem, 0.3).episode(policy)
    probe, sim = run_lockstep(ros, problem, policy, tmp_path / 'policy.json', 0.3)
    layout = JointStateLayout(problem)
    for k in (1, 2):  # the second episode too: the hand-over between episodes keeps step
        end = probe.end_of(k)
        assert end['event'] == ('goal' if ep.reached else 'step_limit')
        assert end['step'] == ep.steps
        assert end['return'] == ep.ret
        assert end['delta_star'] == ep.delta_star
        assert end['goal_delta'] == 0.3
    states = sorted(probe.states.items())
    assert [t for t, _ in states[:ep.steps + 1]] == [k * TICK_NS for k in range(ep.steps + 1)]
    got = np.array([layout.from_msg(m) for _, m in states[:ep.steps + 1]])
    assert np.array_equal(got, ep.states)
    efforts = [m.effort[layout.actuator] for _, m in states[:ep.steps + 1]]
    assert efforts == [0.0] + list(ep.actions)
    assert probe.rewards[:ep.steps] == list(ep.rewards)
    assert probe.indices[:ep.steps] == list(ep.exemplars)
    assert sim.total_steps == 2 * ep.steps  # max_episodes = 2: no third episode


def test_lockstep_pdip_executables_equal_offline_evaluation(ros, tmp_path):
    """pdip_sim and policy_node as processes (params files) give Evaluator's episode exactly."""
    problem = load_problem('pdip')
    policy = random_policies(problem, 1, seed=7)[0]
    ep = Evaluator(problem).episode(policy)
    path = tmp_path / 'pdip.json'
    policy.save(path)
    probe = ros.start(Probe, problem=problem)
    pol = ros.spawn('policy_node', '--ros-args', '--params-file',
                    str(PARAMS_DIR / 'policy_node.yaml'), '-p', 'problem:=pdip',
                    '-p', f'policy_file:={path}')
    sim = ros.spawn('pdip_sim', '--ros-args', '--params-file',
                    str(PARAMS_DIR / 'pdip_sim.yaml'), '-p', 'mode:=lockstep',
                    '-p', 'max_episodes:=1')
    end = ros.wait_for(lambda: probe.end_of(1), 'the end of episode 1', timeout=60.0)
    assert (end['event'], end['step']) == ('step_limit' if not ep.reached else 'goal',
                                           ep.steps)
    assert end['return'] == ep.ret
    assert end['delta_star'] == ep.delta_star
    assert end['goal_delta'] == problem.default_delta
    assert ros.stop(sim) == 0 and ros.stop(pol) == 0  # Ctrl-C: a clean exit


def test_reset_service_starts_a_new_episode_from_the_initial_state(ros):
    """Reset aborts the episode (event 'reset'), restarts from the initial state, new stamp."""
    problem = load_problem('acrobot')
    probe = ros.start(Probe, problem=problem)
    sim = ros.start(SimNode, params={'mode': 'lockstep', 'republish_period': 0.05})
    ros.wait_for(lambda: sim._command_sub.get_publisher_count() and probe.states, 'discovery')
    for k in range(1, 4):
        probe.command_pub.publish(Float64(data=2.0))
        ros.wait_for(lambda k=k: k * TICK_NS in probe.states, f'state {k}')
    response = ros.call(probe.reset, Trigger.Request())
    assert response.success and 'episode 2' in response.message
    reset = ros.wait_for(lambda: probe.event('reset', 1), 'the reset event')
    start = ros.wait_for(lambda: probe.event('start', 2), 'the start of episode 2')
    assert reset['step'] == 3 and start['step'] == 0 and start['return'] == 0.0
    msg = ros.wait_for(lambda: probe.states.get(4 * TICK_NS), 'the new initial state')
    layout = JointStateLayout(problem)
    assert np.array_equal(layout.from_msg(msg), problem.initial_state)
    assert msg.effort[layout.actuator] == 0.0


@pytest.mark.parametrize('name', ['acrobot', 'pdip_single', 'mountain_car'])
def test_bad_commands_are_ignored_or_clamped_and_the_sim_survives(ros, name):
    """NaN/inf commands do not step; out-of-range ones step with the clamped actuator value."""
    problem = load_problem(name)
    limit = max(abs(a) for a in problem.actions)
    mdp_step, params = model_module(problem.model).mdp_step, problem.params()
    layout = JointStateLayout(problem)
    tick = round(problem.dt * problem.substeps * 1e9)  # [ns] sim time per MDP step
    probe = ros.start(Probe, problem=problem)
    sim = ros.start(SimNode, params={'problem': name, 'mode': 'lockstep',
                                     'republish_period': 0.05})
    ros.wait_for(lambda: sim._command_sub.get_publisher_count() and probe.states, 'discovery')
    for value in (math.nan, math.inf, -math.inf):
        probe.command_pub.publish(Float64(data=value))
    ros.wait_for(lambda: sim.commands.ignored == 3, 'three ignored commands')
    assert sim.total_steps == 0
    expected = problem.initial_state
    cases = [(50.0 * limit, limit), (-1e300, -limit), (0.25 * limit, 0.25 * limit)]
    for k, (value, applied) in enumerate(cases, 1):
        probe.command_pub.publish(Float64(data=value))
        msg = ros.wait_for(lambda k=k: probe.states.get(k * tick), f'state {k}')
        mdp_step(expected, applied, params)
        assert np.array_equal(layout.from_msg(msg), expected)
        assert msg.effort[layout.actuator] == applied
        assert list(msg.name) == list(problem.joints)
    assert sim.commands.clamped == 2
    assert ros.call(probe.reset, Trigger.Request()).success  # still serving


def test_realtime_mode_holds_the_last_command_and_publishes_clock(ros):
    """Realtime steps on its own with the held (clamped) command and publishes /clock."""
    problem = load_problem('acrobot')
    layout = JointStateLayout(problem)
    probe = ros.start(Probe, problem=problem)
    clocks = []
    probe.create_subscription(Clock, '/clock', lambda m: clocks.append(m.clock), PROBE_QOS)
    sim = ros.start(SimNode, params={'mode': 'lockstep'})
    ros.wait_for(lambda: sim._command_sub.get_publisher_count(), 'discovery')
    results = sim.set_parameters([Parameter('real_time_factor', value=4.0),
                                  Parameter('mode', value='realtime')])
    assert all(r.successful for r in results)
    probe.command_pub.publish(Float64(data=-7.0))
    ros.wait_for(lambda: sim.commands.clamped == 1, 'the command')
    first = ros.wait_for(lambda: next((t for t, m in list(probe.states.items())
                                       if m.effort[layout.actuator] == -2.0), None),
                         'a state stepped with the clamped command')
    ros.wait_for(lambda: len([t for t in list(probe.states) if t > first]) >= 3,
                 'three more states')
    with probe.lock:
        later = [m for t, m in probe.states.items() if t >= first]
        stamps = list(probe.states)
    assert all(m.effort[layout.actuator] == -2.0 for m in later)  # zero-order hold
    assert stamps == sorted(stamps) and all(t % TICK_NS == 0 for t in stamps)
    ros.wait_for(lambda: clocks, '/clock')
    times = [c.sec * 10**9 + c.nanosec for c in list(clocks)]
    assert times == sorted(times) and all(t % TICK_NS == 0 for t in times)


def test_invalid_parameters_are_refused_with_the_reason(ros):
    """Each invalid parameter value is refused with a reason naming it; settings stay."""
    sim = ros.start(SimNode, params={'mode': 'lockstep'})
    before = sim.settings
    for name, value, words in [
            ('mode', 'fast', 'mode'),
            ('real_time_factor', 0.0,
             'real_time_factor: expected a number in [0.001, 10000], got 0.0'),
            ('real_time_factor', math.nan, 'real_time_factor'), ('delta', -1.0, 'delta'),
            ('n_step', 0, 'n_step'), ('max_episodes', -2, 'max_episodes'),
            ('republish_period', math.inf, 'republish_period'), ('problem', 'pdip', 'problem')]:
        result = sim.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and words in result.reason, (name, result.reason)
    assert sim.settings == before and sim.problem.name == 'acrobot'
    assert sim.set_parameters([Parameter('delta', value=0.5)])[0].successful
    assert sim.settings.delta == 0.5


def test_unknown_problem_exits_with_a_clear_error(ros):
    """An executable given an unknown problem exits with code 2 and names the known ones."""
    proc = ros.spawn('acrobot_sim', '--ros-args', '-p', 'problem:=cartpole')
    proc.wait(60)
    log = ros.children[-1][1].read_text()
    assert proc.returncode == 2
    assert "unknown problem 'cartpole'" in log and 'acrobot' in log
