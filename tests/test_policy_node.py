"""Policy node (sapga_ros/nodes/policy_node.py) over real Fast DDS: state validation, one
answer per stamp, policy files and the load_policy -> get_policy hand-off."""
from __future__ import annotations

import array
import json
import math

import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ros_helpers import Probe, isolated_ros
from sim_nodes.ros.common import JointStateLayout
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.exemplars.distance import distances
from sim_nodes.problem import load_problem


@pytest.fixture(scope='module')
def acrobot():
    return load_problem('acrobot')


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


def random_policy(problem, seed: int, size: int = 60) -> ExemplarPolicy:
    rng = np.random.default_rng(seed)
    return ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (size, problem.dim)),
                          rng.integers(0, 3, size), meta={'seed': seed})


def expected_action(policy: ExemplarPolicy, state: np.ndarray) -> tuple[int, float]:
    """The nearest exemplar by the selector's distance, computed independently of the node."""
    p = policy.problem
    j = int(np.argmin(distances(state, policy.states, p.ranges, p.is_angle)))
    return j, float(policy.action_values[j])


class FakeTrainer(Node):
    """A get_policy Trigger server answering with queued (success, message) pairs in turn."""

    def __init__(self, answers: list[tuple[bool, str]], **kwargs) -> None:
        super().__init__('trainer_node', **kwargs)
        self.answers = list(answers)
        self.calls = 0
        self.service = self.create_service(Trigger, '~/get_policy', self._on_get_policy)

    def _on_get_policy(self, request: Trigger.Request, response: Trigger.Response
                       ) -> Trigger.Response:
        self.calls += 1
        response.success, response.message = self.answers.pop(0)
        return response


def connected(ros, probe: Probe, pol: PolicyNode) -> None:
    ros.wait_for(lambda: pol._state_sub.get_publisher_count() >= 1
                 and pol._command_pub.get_subscription_count() >= 1
                 and pol._index_pub.get_subscription_count() >= 1, 'discovery')


def test_bad_state_messages_are_skipped_and_good_ones_answered_once(ros, acrobot, tmp_path):
    """Wrong lengths, names or NaN are skipped; each good stamp gets exactly one answer."""
    policy = random_policy(acrobot, 1)
    policy.save(tmp_path / 'a.json')
    layout = JointStateLayout(acrobot)
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'a.json')})
    connected(ros, probe, pol)
    rng = np.random.default_rng(5)
    s1, s2 = rng.uniform(acrobot.low, acrobot.high, (2, acrobot.dim))

    short = layout.to_msg(s1, 0.0, 1)
    short.position = array.array('d', [1.0])
    renamed = layout.to_msg(s1, 0.0, 2)
    renamed.name = ['shoulder', 'wrist']
    twice = layout.to_msg(s1, 0.0, 3)
    twice.name = ['elbow', 'elbow']
    nan = layout.to_msg(s1, 0.0, 4)
    nan.velocity = array.array('d', [math.nan, 0.0])
    inf = layout.to_msg(s1, 0.0, 5)
    inf.position = array.array('d', [0.0, math.inf])
    good = layout.to_msg(s1, 0.0, 6)
    reordered = layout.to_msg(s2, 0.0, 7)  # joints in another order: still a valid state
    reordered.name = list(reversed(reordered.name))
    for field in ('position', 'velocity', 'effort'):
        setattr(reordered, field, array.array('d', reversed(getattr(reordered, field))))
    for msg in (short, renamed, twice, nan, inf, good, good, reordered):
        probe.state_pub.publish(msg)

    ros.wait_for(lambda: pol.answered == 2, 'two answers')
    assert pol.rejected == 5
    ros.wait_for(lambda: len(probe.indices) == 2 and len(probe.commands) == 2, 'the commands')
    expected = [expected_action(policy, s1), expected_action(policy, s2)]
    assert probe.indices == [j for j, _ in expected]
    assert probe.commands == [a for _, a in expected]


def test_without_a_policy_nothing_is_published_until_one_is_set(ros, acrobot, tmp_path):
    """With no policy a state is not answered; once a policy is set, its re-publish is."""
    layout = JointStateLayout(acrobot)
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode)
    connected(ros, probe, pol)
    state = layout.to_msg(acrobot.initial_state, 0.0, 0)
    probe.state_pub.publish(state)
    ros.wait_for(lambda: pol.unanswered == 1, 'the state seen')
    assert pol.answered == 0 and pol.active is None
    policy = random_policy(acrobot, 2)
    policy.save(tmp_path / 'p.json')
    assert pol.set_parameters([Parameter('policy_file', value=str(tmp_path / 'p.json'))]
                              )[0].successful
    probe.state_pub.publish(state)  # the lockstep sim's re-publish, same stamp
    ros.wait_for(lambda: probe.commands, 'the command')
    assert (probe.indices[0], probe.commands[0]) == expected_action(
        policy, acrobot.initial_state)


def test_bad_policy_files_are_refused_with_the_reason_and_the_old_policy_kept(
        ros, acrobot, tmp_path):
    """Wrong-problem, malformed, non-finite and missing files are refused; the policy stays."""
    good = tmp_path / 'good.json'
    random_policy(acrobot, 3).save(good)
    pol = ros.start(PolicyNode, params={'policy_file': str(good)})
    active = pol.active
    assert active is not None and len(active) == 60
    pdip = load_problem('pdip')
    random_policy(pdip, 4).save(tmp_path / 'pdip.json')
    (tmp_path / 'broken.json').write_text('{"format": "sapga-policy/1", "exemplars": [')
    doc = random_policy(acrobot, 5).to_document()
    doc['exemplars'][3]['state'][2] = 1e999  # json.dumps writes Infinity
    (tmp_path / 'inf.json').write_text(json.dumps(doc))
    doc = random_policy(acrobot, 5).to_document()
    doc['exemplars'][0]['action'] = 1.0
    (tmp_path / 'action.json').write_text(json.dumps(doc))
    cases = [('pdip.json', "policy is for 'pdip'"), ('broken.json', 'malformed JSON'),
             ('inf.json', 'Infinity'), ('action.json', 'exemplars[0].action'),
             ('missing.json', 'cannot read')]
    for name, words in cases:
        result = pol.set_parameters([Parameter('policy_file', value=str(tmp_path / name))])[0]
        assert not result.successful and words in result.reason, (name, result.reason)
        assert pol.active is active
        assert pol.get_parameter('policy_file').value == str(good)
    other = tmp_path / 'other.json'
    random_policy(acrobot, 6, size=80).save(other)
    assert pol.set_parameters([Parameter('policy_file', value=str(other))])[0].successful
    assert pol.active is not active and len(pol.active) == 80
    assert pol.active.source == str(other)


@pytest.mark.parametrize('content', ['not json', None])
def test_a_bad_policy_file_at_start_is_one_line_and_exit_2(ros, tmp_path, content):
    """policy_node started with a broken or missing policy file stops at once: one line
    naming the file, exit status 2, no traceback (a node with no policy would answer
    nothing)."""
    path = tmp_path / 'broken.json'
    if content is not None:
        path.write_text(content)
    proc = ros.spawn('policy_node', '--ros-args', '-p', f'policy_file:={path}')
    proc.wait(120)
    lines = [line for line in ros.children[-1][1].read_text().splitlines() if line.strip()]
    assert proc.returncode == 2, lines
    assert len(lines) == 1 and lines[0].startswith('policy_node: error: '), lines
    assert str(path) in lines[0] and 'Traceback' not in lines[0]


def test_load_policy_fetches_from_the_trainer_service_and_validates(ros, acrobot, tmp_path):
    """load_policy calls get_policy; bad answers are refused with the reason, a good one swaps."""
    first = tmp_path / 'first.json'
    random_policy(acrobot, 7).save(first)
    good = random_policy(acrobot, 8, size=90)
    trainer = ros.start(FakeTrainer, answers=[
        (True, random_policy(load_problem('pdip'), 9).to_json()),
        (True, '{"format": "sapga-policy/1",'),
        (False, 'no policy trained yet'),
        (True, good.to_json())])
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode, params={'policy_file': str(first)})
    active = pol.active
    for words in ("policy is for 'pdip'", 'malformed JSON', 'no policy trained yet'):
        response = ros.call(probe.load_policy, Trigger.Request())
        assert not response.success and words in response.message, response.message
        assert pol.active is active
    response = ros.call(probe.load_policy, Trigger.Request())
    assert response.success and '90 exemplars' in response.message
    assert trainer.calls == 4
    assert np.array_equal(pol.active.policy.states, good.states)
    assert np.array_equal(pol.active.policy.actions, good.actions)


def test_load_policy_without_a_trainer_fails_with_the_reason(ros, acrobot):
    """With no trainer service, load_policy answers failure after load_timeout, not a hang."""
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode, params={'trainer_service': 'no_trainer', 'load_timeout': 0.3})
    response = ros.call(probe.load_policy, Trigger.Request())
    assert not response.success and 'no_trainer is not available' in response.message
    assert pol.active is None


def test_a_node_with_a_delay_runs_plain_policies_ahead_and_refuses_the_others(
        ros, acrobot, tmp_path):
    """delay:=1 runs every plain exemplar file (and a policy from the trainer) as designed
    for one step of delay; a hybrid or a file with its own delay is refused, naming it, and
    the policy in use stays."""
    from sapga_ros.evaluation.classical_design import classical_policy
    from sapga_ros.policies.classical import AHEAD_KIND, ahead, with_catch
    plain = tmp_path / 'plain.json'
    random_policy(acrobot, 3).save(plain)
    hybrid = tmp_path / 'hybrid.json'
    hybrid.write_text(with_catch(random_policy(acrobot, 4),
                                 classical_policy(acrobot, c=0.1)).to_json())
    own = tmp_path / 'own.json'
    own.write_text(ahead(random_policy(acrobot, 5), 2).to_json())
    trainer = ros.start(FakeTrainer, answers=[(True, hybrid.read_text()),
                                              (True, random_policy(acrobot, 6).to_json())])
    probe = ros.start(Probe, problem=acrobot)
    pol = ros.start(PolicyNode, params={'policy_file': str(plain), 'delay': 1})
    active = pol.active
    assert active.policy.kind == AHEAD_KIND and active.policy.delay == 1
    assert active.selector.stateful
    for path, words in ((hybrid, 'only a plain exemplar policy'),
                        (own, 'designed for a delay of 2')):
        result = pol.set_parameters([Parameter('policy_file', value=str(path))])[0]
        assert not result.successful and str(path) in result.reason, result.reason
        assert words in result.reason and pol.active is active
    response = ros.call(probe.load_policy, Trigger.Request())
    assert not response.success and 'only a plain exemplar policy' in response.message
    response = ros.call(probe.load_policy, Trigger.Request())
    assert response.success and pol.active.policy.delay == 1 and trainer.calls == 2
