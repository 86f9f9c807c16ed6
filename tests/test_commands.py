"""Commands answer states (sim_nodes/ros/commands.py) over real Fast DDS: a lockstep
simulator steps only on the stamped command for its current state, so a reset with a command
in flight never steps the new episode with it; a realtime simulator applies the latest
command and counts the states no command answered in time; malformed stamped commands are
ignored and the node goes on."""
from __future__ import annotations

import array
import math

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from ros_helpers import Probe, isolated_ros
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout, stamp_ns
from sim_nodes.ros.sim_node import SimNode

TICK_NS = 50_000_000  # sim time per new state of the pendulums: 0.05 s


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


@pytest.fixture(scope='module')
def acrobot():
    return load_problem('acrobot')


def lockstep(ros, problem, **params):
    """A probe and a lockstep simulator (publishing its first state) that hear each other."""
    probe = ros.start(Probe, problem=problem)
    sim = ros.start(SimNode, params={'problem': problem.name, 'mode': 'lockstep',
                                     'republish_period': 0.05, **params})
    ros.wait_for(lambda: sim._stamped_sub.get_publisher_count() and probe.states, 'discovery')
    return probe, sim


def test_lockstep_ignores_and_counts_commands_for_other_states(ros, acrobot):
    """Commands stamped with a state that is not the current one (future, past, duplicate)
    never step; the one for the current state steps exactly once."""
    probe, sim = lockstep(ros, acrobot)
    for stamp in (TICK_NS, -TICK_NS, 7 * TICK_NS):
        probe.answer(2.0, stamp)
    ros.wait_for(lambda: sim.commands.late == 3, 'three late commands')
    assert sim.total_steps == 0
    probe.answer(-2.0, 0)
    ros.wait_for(lambda: TICK_NS in probe.states, 'state 1')
    probe.answer(-2.0, 0)                     # answered already: the state is no longer current
    ros.wait_for(lambda: sim.commands.late == 4, 'the duplicate counted')
    assert sim.total_steps == 1 and max(probe.states) == TICK_NS
    layout = JointStateLayout(acrobot)
    assert probe.states[TICK_NS].effort[layout.actuator] == -2.0


def test_a_reset_with_a_command_in_flight_never_steps_the_new_episode_with_it(ros, acrobot):
    """The answer to the aborted episode's last state arrives after the reset: it is ignored
    (and counted in the new episode's events); the new episode steps on its own answer."""
    layout = JointStateLayout(acrobot)
    probe, sim = lockstep(ros, acrobot)
    probe.answer(2.0, 0)
    ros.wait_for(lambda: TICK_NS in probe.states, 'state 1')
    assert ros.call(probe.reset, Trigger.Request()).success
    start = ros.wait_for(lambda: probe.event('start', 2), 'the start of episode 2')
    assert start['time'] * 1e9 == pytest.approx(2 * TICK_NS)
    probe.answer(2.0, TICK_NS)                # in flight: answers the aborted state 1
    ros.wait_for(lambda: sim.commands.late == 1, 'the stale command counted')
    assert sim.total_steps == 1 and max(probe.states) == 2 * TICK_NS
    probe.answer(-2.0, 2 * TICK_NS)
    msg = ros.wait_for(lambda: probe.states.get(3 * TICK_NS), 'the first step of episode 2')
    # the positive proof that the stale command stepped nothing: the one step of episode 2
    # is its own answer's, from the initial state, and no other state came between
    expected = acrobot.initial_state
    model_module(acrobot.model).mdp_step(expected, -2.0, acrobot.params())
    assert np.array_equal(layout.from_msg(msg), expected)
    assert msg.effort[layout.actuator] == -2.0
    assert sorted(probe.states) == [0, TICK_NS, 2 * TICK_NS, 3 * TICK_NS]
    assert sim.total_steps == 2
    assert ros.call(probe.reset, Trigger.Request()).success
    reset = ros.wait_for(lambda: probe.event('reset', 2), 'the reset event of episode 2')
    assert reset['late_commands'] == 1 and reset['step'] == 1


def test_resets_during_a_running_policy_never_mix_episodes(ros, tmp_path, acrobot):
    """A policy node answering a lockstep simulator, reset again and again mid-episode:
    each reset starts the next episode, and the states split into the episodes exactly:
    every episode's states are the start of the offline episode, its end event counts them,
    none is missing, none is another episode's.

    No auto_reset, so that the 12 resets alone start episodes: on a slow machine an episode
    can reach its 400 steps between two resets, and would then start one more episode by
    itself; here it waits for the reset instead (the waits below take that end for 'a few
    steps').  The last episode runs to its end, so nothing more comes after it and the
    states and events compared are all of the run's."""
    rng = np.random.default_rng(4)
    policy = ExemplarPolicy(acrobot, rng.uniform(acrobot.low, acrobot.high, (60, 4)),
                            rng.integers(0, 3, 60))
    offline = Evaluator(acrobot, 0.0).episode(policy)          # the full 400 steps
    layout = JointStateLayout(acrobot)
    policy.save(tmp_path / 'p.json')
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode)
    sim = ros.start(SimNode, params={'mode': 'lockstep', 'delta': 0.0, 'markers': False,
                                     'republish_period': 0.05, 'auto_reset': False})
    ros.wait_for(lambda: sim._stamped_sub.get_publisher_count() == 2
                 and sim._state_pub.get_subscription_count() == 2, 'discovery')
    # the policy once everything is matched: its first answer is not lost
    assert pol.set_parameters([Parameter('policy_file', value=str(tmp_path / 'p.json'))]
                              )[0].successful
    ros.wait_for(lambda: len(probe.states) > 3, 'the loop running')
    for k in range(12):
        before = len(probe.states)
        ros.wait_for(lambda: len(probe.states) > before + 5 + k or probe.end_of(k + 1),
                     'a few steps (or the end of the episode)')
        answer = ros.call(probe.reset, Trigger.Request())
        assert answer.success and answer.message == f'episode {k + 2} started'
    last = ros.wait_for(lambda: probe.end_of(13), 'the end of the last episode')
    final = round(last['time'] * 1e9)
    ros.wait_for(lambda: final in probe.states, 'the last state')
    with probe.lock:
        events = list(probe.events)
        states = dict(probe.states)
    starts = [round(e['time'] * 1e9) for e in events if e['event'] == 'start']
    assert [e['episode'] for e in events if e['event'] == 'start'] == list(range(1, 14))
    assert max(states) == final
    for episode, (begin, end) in enumerate(zip(starts, starts[1:] + [final + TICK_NS]), 1):
        got = [layout.from_msg(states[t]) for t in range(begin, end, TICK_NS) if t in states]
        assert len(got) == (end - begin) // TICK_NS, 'a state missing'
        assert np.array_equal(np.array(got), offline.states[:len(got)])
        ended = [e for e in events if e['episode'] == episode and e['event'] != 'start']
        assert len(ended) == 1 and ended[0]['step'] == len(got) - 1, ended
        assert ended[0]['event'] == ('reset' if len(got) < len(offline.states) else
                                     'step_limit')
    assert sim.commands.ignored == 0


def test_realtime_applies_the_latest_command_and_counts_unanswered_states(ros, acrobot):
    """Realtime holds the latest command, even one answering a long-gone state; every state
    that no command answered before the next tick is late: with nobody answering, all of an
    episode's states (node and the episode's end event)."""
    layout = JointStateLayout(acrobot)
    probe = ros.start(Probe, problem=acrobot)
    sim = ros.start(SimNode, params={'mode': 'lockstep', 'n_step': 60})
    ros.wait_for(lambda: sim._stamped_sub.get_publisher_count(), 'discovery')
    assert sim.set_parameters([Parameter('real_time_factor', value=4.0),
                               Parameter('mode', value='realtime')])[0].successful
    ros.wait_for(lambda: len(probe.states) > 5, 'realtime steps')
    probe.answer(-2.0, 0)                     # answers the first state: long gone
    held = ros.wait_for(lambda: next((t for t, m in list(probe.states.items())
                                      if m.effort[layout.actuator] == -2.0), None),
                        'a step with the late command')
    current = max(probe.states)
    probe.answer(2.0, current + 100 * TICK_NS)   # a future state's answer: held all the same
    ros.wait_for(lambda: any(m.effort[layout.actuator] == 2.0 for t, m in
                             list(probe.states.items()) if t > held), 'the next command held')
    episode = sim._episode + 1                # a whole episode that nobody answers
    end = ros.wait_for(lambda: probe.end_of(episode), f'the end of episode {episode}')
    assert end['step'] == 60 and end['late_commands'] == 60      # every state it stepped from


def test_realtime_late_commands_count_exactly_the_unanswered_states(ros, acrobot, tmp_path):
    """With a policy node answering, an episode's late_commands is at least the number of its
    states the policy never answered (a probe hears every answer) and at most its steps."""
    ExemplarPolicy(acrobot, acrobot.initial_state[None, :], [2]).save(tmp_path / 'p.json')
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'p.json')})
    sim = ros.start(SimNode, params={'real_time_factor': 2.0, 'n_step': 40,
                                     'max_episodes': 2})
    end = ros.wait_for(lambda: probe.end_of(2), 'two episodes')
    # the answers (the policy node's topic) can arrive after the end event (the sim's)
    ros.wait_for(lambda: len(probe.answered) >= pol.answered, 'every answer sent')
    start = probe.event('start', 2)
    with probe.lock:
        stamps = [t for t in probe.states if start['time'] * 1e9 - 1 <= t
                  < end['time'] * 1e9 - 1]
        answered = set(probe.answered)
    never = [t for t in stamps if t not in answered]
    assert len(stamps) == end['step'] == 40
    assert len(never) <= end['late_commands'] <= end['step']
    assert sim.commands.late >= end['late_commands']


@pytest.mark.parametrize('name', ['acrobot', 'pdip'])
def test_malformed_stamped_commands_are_ignored_and_the_sim_goes_on(ros, name):
    """No actuator joint, efforts not matching names, NaN: ignored with a count; a good one
    (joints in any order, extra joints) then steps, clamped to the actuator limit."""
    problem = load_problem(name)
    limit = max(abs(a) for a in problem.actions)
    probe, sim = lockstep(ros, problem)
    joint = problem.actuator_joint
    cases = [([], []), (['wrist'], [1.0]), ([joint], []), ([joint, 'x'], [1.0]),
             ([joint], [math.nan])]
    for names, effort in cases:
        probe.stamped_pub.publish(JointState(name=names, effort=array.array('d', effort)))
    ros.wait_for(lambda: sim.commands.ignored == len(cases), 'the bad commands counted')
    assert sim.total_steps == 0
    probe.stamped_pub.publish(JointState(name=['other', joint],
                                         effort=array.array('d', [9.0, 10 * limit])))
    state = ros.wait_for(lambda: probe.states.get(round(problem.dt * problem.substeps * 1e9)),
                         'the step')
    assert state.effort[JointStateLayout(problem).actuator] == limit
    assert stamp_ns(state) > 0 and sim.commands.clamped == 1
    probe.command_pub.publish(Float64(data=0.0))   # the hand-use topic still answers
    ros.wait_for(lambda: sim.total_steps == 2, 'a hand-use step')
