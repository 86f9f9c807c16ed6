"""Policies loaded off the policy node's executor thread (sapga_ros/nodes/policy_loader.py):
a large policy file set over the parameter service loads in a worker while the old policy
keeps answering states, then swaps in; one that fails is logged and the parameter reverts."""
from __future__ import annotations

import threading

import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter

from ros_helpers import Probe, isolated_ros
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import SYNC_BYTES, PolicyNode
from sim_nodes.ros.common import JointStateLayout

LARGE = 280_000      # exemplars: about 30 MB of policy file
WAIT_LOAD_S = 300.0  # [s] for the large file to load on a loaded machine


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def policy(problem, seed: int, size: int) -> ExemplarPolicy:
    rng = np.random.default_rng(seed)
    return ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (size, problem.dim)),
                          rng.integers(0, 3, size))


def set_over_the_service(ros, probe: Probe, node: str, path: str):
    """Set policy_file as ``ros2 param set`` does: the node's executor runs the request."""
    client = probe.create_client(SetParameters, f'/{node}/set_parameters')
    request = SetParameters.Request(parameters=[
        Parameter('policy_file', value=path).to_parameter_msg()])
    return ros.call(client, request).results[0]


def test_states_are_answered_while_a_large_policy_loads_then_it_swaps_in(ros, acrobot_problem,
                                                                         tmp_path):
    """While a 30 MB policy file set through the parameter service loads, every new state
    is answered with the old policy; then the large one answers."""
    small, large = tmp_path / 'small.json', tmp_path / 'large.json'
    old = policy(acrobot_problem, 1, 40)
    old.save(small)
    new = policy(acrobot_problem, 2, LARGE)
    new.save(large)
    assert large.stat().st_size > 25e6 and small.stat().st_size < SYNC_BYTES
    probe = ros.start(Probe, problem=acrobot_problem)
    pol = ros.start(PolicyNode, params={'policy_file': str(small)})
    ros.wait_for(lambda: pol._state_sub.get_publisher_count() >= 1
                 and pol._command_pub.get_subscription_count() >= 1, 'discovery')
    layout = JointStateLayout(acrobot_problem)
    rng = np.random.default_rng(3)
    result = set_over_the_service(ros, probe, 'policy_node', str(large))
    assert result.successful, result.reason
    reference = StateSelector(old)
    answered_while_loading = 0
    stamp = 0
    while pol.loading == str(large):
        stamp += 1
        s = rng.uniform(acrobot_problem.low, acrobot_problem.high)
        probe.state_pub.publish(layout.to_msg(s, 0.0, stamp))
        ros.wait_for(lambda: stamp in probe.answered or pol.loading is None,
                     'an answer or the end of the load', WAIT_LOAD_S)
        with probe.lock:
            answers = dict(zip(probe.answered, probe.commands))
        if stamp in answers and pol.active.source == str(small):   # the old one answered
            assert answers[stamp] == reference.select(s)[1]
            answered_while_loading += 1
    assert answered_while_loading >= 3
    ros.wait_for(lambda: pol.active.source == str(large), 'the swap', WAIT_LOAD_S)
    assert len(pol.active) == LARGE and pol.get_parameter('policy_file').value == str(large)
    stamp += 1
    probe.state_pub.publish(layout.to_msg(acrobot_problem.initial_state, 0.0, stamp))
    ros.wait_for(lambda: stamp in probe.answered, 'an answer of the large policy')


def test_a_large_policy_file_that_fails_is_logged_and_the_parameter_reverts(ros, acrobot_problem,
                                                                            tmp_path):
    """A large file that turns out malformed leaves the old policy in use, and policy_file
    names the old file again."""
    small, broken = tmp_path / 'small.json', tmp_path / 'broken.json'
    policy(acrobot_problem, 1, 40).save(small)
    text = policy(acrobot_problem, 2, 5000).to_json()
    broken.write_text(text[: len(text) // 2])          # cut: malformed JSON
    assert broken.stat().st_size > SYNC_BYTES
    probe = ros.start(Probe, problem=acrobot_problem)
    pol = ros.start(PolicyNode, params={'policy_file': str(small)})
    active = pol.active
    assert set_over_the_service(ros, probe, 'policy_node', str(broken)).successful
    ros.wait_for(lambda: pol.get_parameter('policy_file').value == str(small),
                 'policy_file to revert', WAIT_LOAD_S)
    assert pol.active is active and pol.loading is None


def test_a_small_policy_set_while_a_large_one_loads_wins(ros, acrobot_problem, tmp_path):
    """The newest request counts: a large load that ends after a small file was set is
    dropped."""
    first, large, last = (tmp_path / f'{n}.json' for n in ('first', 'large', 'last'))
    policy(acrobot_problem, 1, 40).save(first)
    policy(acrobot_problem, 2, 20_000).save(large)
    policy(acrobot_problem, 3, 50).save(last)
    pol = ros.start(PolicyNode, params={'policy_file': str(first)})
    assert pol.set_parameters([Parameter('policy_file', value=str(large))])[0].successful
    assert pol.loading == str(large)
    assert pol.set_parameters([Parameter('policy_file', value=str(last))])[0].successful
    assert pol.active.source == str(last) and pol.loading is None
    ros.wait_for(lambda: not any(t.name.startswith('policy-load')
                                 for t in threading.enumerate()),
                 'the large load to end', WAIT_LOAD_S)
    assert pol.active.source == str(last) and len(pol.active) == 50
