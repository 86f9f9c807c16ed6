"""A recorder that falls behind a lockstep run and is then stopped loses nothing that reached
it, over real Fast DDS.

The recorder is taken off the executor (descheduled, as a starved process is; DDS still
receives into its subscriptions' histories) for two whole 400-step episodes and then stopped:
the finished bag holds every message of the run, as the launch's own check and the mcap
library read it.  (The executor takes one message per topic per turn, so ``markers``, which
carries the simulator's scene and the policy's ghost, is always the furthest behind.)
"""
from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from rclpy.parameter import Parameter

from ros_helpers import Probe, isolated_ros
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.recorder_node import RecorderNode
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.verify import recording_gaps
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import topic_names
from sim_nodes.ros.sim_node import SimNode

EPISODES = 2


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


@pytest.mark.parametrize('stop', ['destroy', 'context shutdown'])
def test_a_recorder_stopped_while_behind_writes_every_message_it_received(ros, tmp_path, stop):
    """``destroy``: the node is destroyed (``destroy_node``, as cleanup); ``context
    shutdown``: the context is shut down first, as Ctrl-C and SIGTERM do to the recorder
    process, so the graph can no longer be asked (the topics' offered QoS)."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(5)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (40, 4)),
                            rng.integers(0, 3, 40))
    recorder = ros.start(RecorderNode, params={'problem': 'acrobot', 'bag': 'run',
                                               'output_dir': str(tmp_path / 'rec')})
    probe = ros.start(Probe, problem=problem)
    pol = ros.start(PolicyNode, params={'problem': 'acrobot'})
    sim = ros.start(SimNode, params={'problem': 'acrobot', 'mode': 'lockstep', 'delta': 0.0,
                                     'max_episodes': EPISODES, 'republish_period': 0.05})
    ros.wait_for(lambda: sim._state_pub.get_subscription_count() == 3
                 and sim._stamped_sub.get_publisher_count() == 2 and probe.states
                 and not recorder.missing(), 'discovery of every node and the recorder')
    ros.executor.remove_node(recorder)          # descheduled: takes nothing from now on
    before = recorder.message_count
    policy.save(tmp_path / 'p.json')
    assert pol.set_parameters([Parameter('policy_file', value=str(tmp_path / 'p.json'))]
                              )[0].successful
    ros.wait_for(lambda: sim.total_steps > 0, 'the first step')
    # no more re-published states: on a slow machine they would fill the histories
    assert sim.set_parameters([Parameter('republish_period', value=0.0)])[0].successful
    for k in range(1, EPISODES + 1):
        ros.wait_for(lambda k=k: probe.end_of(k), f'the end of episode {k}')
    ends = [probe.end_of(k) for k in range(1, EPISODES + 1)]
    steps = sum(e['step'] for e in ends)
    assert steps == EPISODES * problem.n_step     # delta 0: every episode runs to the limit
    ros.wait_for(lambda: probe.heard(steps + EPISODES, steps), 'the whole run')
    ros.wait_for(lambda: all(sub.get_publisher_count() for sub, _, _ in
                             recorder._subs.values()), 'the recorder still matched')
    assert recorder.message_count - before < 10   # it really was behind: (almost) nothing yet

    ros.nodes.remove(recorder)
    if stop == 'context shutdown':
        ros.context.try_shutdown()
    recorder.destroy_node()                     # stopped: finishes the bag
    bag = tmp_path / 'rec' / 'run'
    topics = {role: f'/{name}' for role, name in topic_names(problem).items()}
    assert recording_gaps(read_recording(bag), topics, ends, lockstep=True) == []
    (path,) = bag.glob('*.mcap')
    counts: dict[str, int] = {}
    with open(path, 'rb') as f:                 # read back by the mcap library, file order
        times = []
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            times.append(message.log_time)
    assert times == sorted(times)               # written in the order received
    answers = steps + EPISODES - 1              # the last state of a run gets no answer
    assert counts['/reward'] == steps
    assert counts['/exemplar_index'] >= answers and counts['/joint_states'] >= steps + EPISODES
    assert counts['/markers'] >= steps + EPISODES + answers
    assert sum(d.count for d in recorder.dropped.values()) == 0
