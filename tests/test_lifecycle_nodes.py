"""The recorder and the trainer as managed (lifecycle) nodes over real DDS: ``managed:=true``
starts each unconfigured, and lifecycle_msgs/srv/ChangeState requests (what ``ros2 lifecycle
set`` sends) take it through configure, activate, deactivate and cleanup; a configure that
fails (a bad parameter, an output directory that cannot be made, a policy file that cannot be
read) is one error line and leaves it unconfigured and alive
(sapga_ros/nodes/recorder_node.py, trainer_node.py)."""
from __future__ import annotations

from pathlib import Path

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from ros_helpers import isolated_ros
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.recording.reader import decode_messages, read_recording
from sim_nodes.problem import load_problem

TOPIC = '/probe_data'


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class Manager(Node):
    """What a lifecycle manager (or ``ros2 lifecycle set``) uses: the node's lifecycle
    services, a service of its own (``ready`` or ``get_policy``), its parameters, and a
    publisher of the recorded topic."""

    def __init__(self, target: str = 'recorder_node', service: str = 'ready',
                 **kwargs) -> None:
        super().__init__('manager', **kwargs)
        self.change = self.create_client(ChangeState, f'/{target}/change_state')
        self.get = self.create_client(GetState, f'/{target}/get_state')
        self.ready = self.create_client(Trigger, f'/{target}/{service}')
        self.params = self.create_client(SetParameters, f'/{target}/set_parameters')
        self.pub = self.create_publisher(Float64, TOPIC, QoSProfile(
            depth=100, reliability=ReliabilityPolicy.RELIABLE))


def state(ros, m: Manager) -> str:
    return ros.call(m.get, GetState.Request()).current_state.label


def transition(ros, m: Manager, transition_id: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition_id
    return ros.call(m.change, request).success


def set_string(ros, m: Manager, name: str, value: str) -> bool:
    request = SetParameters.Request()
    request.parameters = [ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_STRING, string_value=value))]
    return ros.call(m.params, request).results[0].successful


def spawn_managed(ros, out: Path, *params: str):
    return ros.spawn('recorder_node', '--ros-args', '-p', 'managed:=true', '-p',
                     f'output_dir:={out}', '-p', f'topics:=["{TOPIC}:std_msgs/msg/Float64"]',
                     '-p', 'flush_period:=0.2', *params)


def log_of(ros, proc) -> str:
    return next(log for p, log in ros.children if p is proc).read_text(errors='replace')


def test_configure_activate_deactivate_cleanup(ros, tmp_path):
    """unconfigured -> configure (the bag is made) -> activate (it records what is
    published) -> deactivate -> cleanup (the bag is finished); the node lives on."""
    proc = spawn_managed(ros, tmp_path / 'out', '-p', 'bag:=run1')
    m = ros.start(Manager)
    bag = tmp_path / 'out' / 'run1'
    assert state(ros, m) == 'unconfigured' and not bag.exists()
    assert not ros.call(m.ready, Trigger.Request()).success
    assert transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'inactive' and bag.is_dir()
    for _ in range(10):
        m.pub.publish(Float64(data=-1.0))       # inactive: not subscribed, not recorded
    assert transition(ros, m, Transition.TRANSITION_ACTIVATE)
    assert state(ros, m) == 'active'
    ros.wait_for(lambda: ros.call(m.ready, Trigger.Request()).success, 'the recorder ready')
    sent = [0]

    def recorded() -> bool:     # publish until a chunk with our messages is on disk
        m.pub.publish(Float64(data=float(sent[0])))
        sent[0] += 1
        return any(len(read_recording(f).messages) >= 5 for f in bag.glob('*.mcap'))
    ros.wait_for(recorded, 'messages in the bag')
    assert transition(ros, m, Transition.TRANSITION_DEACTIVATE)
    assert state(ros, m) == 'inactive'
    assert transition(ros, m, Transition.TRANSITION_CLEANUP)
    assert state(ros, m) == 'unconfigured' and proc.poll() is None
    rec = read_recording(bag)
    assert rec.complete, rec.error      # finished: summary, footer, metadata.yaml
    values = [d.value.data for d in decode_messages(rec)[0]]
    assert len(values) >= 5 and -1.0 not in values and values == sorted(values)
    assert set(values) <= set(
        map(float, range(sent[0])))
    assert f'wrote {bag}: {len(values)} messages' in log_of(ros, proc)
    assert ros.stop(proc) == 0


def test_a_failing_configure_stays_unconfigured_and_can_be_retried(ros, tmp_path):
    """A bag name that is not a plain name, then an output directory under a file: each
    configure fails with one error line, the node stays unconfigured and alive; with the
    parameter set right and the file gone, configure succeeds."""
    blocker = tmp_path / 'blocker'
    blocker.write_text('a file, not a directory')
    proc = spawn_managed(ros, blocker / 'out', '-p', 'bag:=a/b')
    m = ros.start(Manager)
    assert state(ros, m) == 'unconfigured'
    assert not transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'unconfigured' and proc.poll() is None
    lines = [ln for ln in log_of(ros, proc).splitlines() if 'configure failed' in ln]
    assert len(lines) == 1 and "bag 'a/b'" in lines[0], log_of(ros, proc)
    assert set_string(ros, m, 'bag', 'good')
    assert not transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'unconfigured' and proc.poll() is None
    lines = [ln for ln in log_of(ros, proc).splitlines() if 'configure failed' in ln]
    assert len(lines) == 2 and str(blocker) in lines[1], lines
    blocker.unlink()
    assert transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'inactive' and (blocker / 'out' / 'good').is_dir()
    assert ros.stop(proc) == 0
    assert read_recording(blocker / 'out' / 'good').bag_metadata is not None


def test_the_trainer_answers_only_while_active(ros, tmp_path):
    """A managed trainer refuses get_policy until active; a configure with a policy file
    that cannot be read fails with one line; with a readable one set, configure and
    activate serve it; deactivate refuses again; cleanup leaves it unconfigured."""
    problem = load_problem('acrobot')
    good = tmp_path / 'policy.json'
    ExemplarPolicy(problem, problem.initial_state[None, :], [2]).save(good)
    missing = tmp_path / 'missing.json'
    proc = ros.spawn('trainer_node', '--ros-args', '-p', 'managed:=true', '-p',
                     f'policy_file:={missing}')
    m = ros.start(Manager, target='trainer_node', service='get_policy')
    assert state(ros, m) == 'unconfigured'
    answer = ros.call(m.ready, Trigger.Request())
    assert not answer.success and 'unconfigured' in answer.message
    assert not transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'unconfigured' and proc.poll() is None
    lines = [ln for ln in log_of(ros, proc).splitlines() if 'configure failed' in ln]
    assert len(lines) == 1 and str(missing) in lines[0], log_of(ros, proc)
    assert set_string(ros, m, 'policy_file', str(good))
    assert transition(ros, m, Transition.TRANSITION_CONFIGURE)
    assert state(ros, m) == 'inactive'
    assert not ros.call(m.ready, Trigger.Request()).success
    assert transition(ros, m, Transition.TRANSITION_ACTIVATE)
    answer = ros.call(m.ready, Trigger.Request())
    assert answer.success and answer.message == good.read_text()
    assert transition(ros, m, Transition.TRANSITION_DEACTIVATE)
    answer = ros.call(m.ready, Trigger.Request())
    assert not answer.success and 'inactive' in answer.message
    assert transition(ros, m, Transition.TRANSITION_CLEANUP)
    assert state(ros, m) == 'unconfigured' and proc.poll() is None
    assert ros.stop(proc) == 0
