"""Tests of ``sapga inspect`` (recording/inspect.py, cli/recordings.py) on synthetic bags.

The bags are written with the core writer (no ROS graph), so every number the summary should
report is known in advance; ``sapga inspect`` takes the bag directory or one storage file.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Int32, String

from sapga_ros.cli import main as cli
from sapga_ros.cli.recordings import run_inspect
from sapga_ros.recording.events import ROLE_TYPES
from sapga_ros.recording.metadata import TopicInfo, qos_profile
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.writer import BagWriter
from sim_nodes.goal import delta_of
from sim_nodes.problem import load_problem

TOPICS = {'state': '/joint_states', 'command': '/command', 'reward': '/reward',
          'event': '/episode_event', 'exemplar': '/exemplar_index',
          'command_stamped': '/command_stamped'}


def acrobot_states(n: int) -> list[list[float]]:
    """n acrobot states swinging from hanging (3pi/2) to exactly upright at rest (pi/2)."""
    return [[1.5 * math.pi - math.pi * k / (n - 1), 0.1 * math.sin(k) * (k < n - 1),
             -1.0 * (k < n - 1), 0.5 * (k < n - 1)] for k in range(n)]


def pdip_states(n: int) -> list[list[float]]:
    return [[0.1 * k, 0.2, 1.5 * math.pi - 0.1 * k, 1.5 * math.pi - 0.05 * k, -0.3, 0.4]
            for k in range(n)]


def new_bag(path: Path, metadata: dict | None, chunk_size: int = 1024) -> BagWriter:
    """A bag writer with the five role topics registered."""
    writer = BagWriter(path, chunk_size=chunk_size, custom_data=metadata,
                       file_metadata=metadata)
    for role, topic in TOPICS.items():
        writer.add_topic(TopicInfo(topic, ROLE_TYPES[role], [qos_profile()]))
    return writer


def write_recording(path_dir: Path, problem_name: str, episodes: list[dict], *,
                    chunk_size: int = 1024, metadata: bool = True,
                    stamped: bool = False, sent: bool = True, stray: bool = False) -> Path:
    """A one-file bag of the given episodes (dicts of states, commands, rewards, end, and
    optionally late: the end event's late_commands); commands on ``command`` or, if
    ``stamped``, on ``command_stamped`` as the policy node answers; publish times 0 (not
    known) unless ``sent``; with ``stray``, a reward of 100 after each end event (between
    episodes: none's); returns its storage file (the bag directory is its parent)."""
    problem = load_problem(problem_name)
    meta = {'problem': problem_name, 'delta': '0.02',
            'topics': json.dumps(TOPICS)} if metadata else None
    t = [1_700_000_000_000_000_000]
    step = [0]

    def put(writer: BagWriter, role: str, msg: object) -> None:
        t[0] += 1_000_000
        writer.write(TOPICS[role], serialize_message(msg), t[0], t[0] if sent else 0)

    with new_bag(path_dir / f'{problem_name}_bag', meta, chunk_size) as writer:
        for number, ep in enumerate(episodes):
            put(writer, 'event', String(data=json.dumps({'event': 'start', 'episode': number,
                                                         'step': 0, 'time': step[0] * 0.05})))
            for k, s in enumerate(ep['states']):
                put(writer, 'state', joint_state(problem, s, step[0]))
                step[0] += 1
                if k < len(ep['commands']) and stamped:
                    answer = joint_state(problem, s, step[0] - 1)
                    answer.name, answer.position, answer.velocity = \
                        [problem.actuator_joint], [], []
                    answer.effort = [ep['commands'][k]]
                    put(writer, 'command_stamped', answer)
                elif k < len(ep['commands']):
                    put(writer, 'command', Float64(data=ep['commands'][k]))
                if k < len(ep['commands']):
                    put(writer, 'exemplar', Int32(data=k % 5))
                    put(writer, 'reward', Float64(data=ep['rewards'][k]))
            end = {'event': ep['end'], 'episode': number, 'step': len(ep['rewards']),
                   'return': sum(ep['rewards']), 'goal_delta': 0.02,
                   'delta_star': min(delta_of(problem, s) for s in ep['states']),
                   'time': (step[0] - 1) * 0.05}
            if 'late' in ep:
                end['late_commands'] = ep['late']
            end.update(ep.get('end_fields', {}))
            put(writer, 'event', String(data=json.dumps(end)))
            if stray:
                put(writer, 'reward', Float64(data=100.0))
    return writer.paths[0]


def write_received(path: Path, log: list[tuple[int, str, object, int]]) -> Path:
    """An acrobot bag of ``log`` (receive time, topic, message, publish time), written in
    receive order as a recorder writes it; its storage file."""
    with new_bag(path, {'problem': 'acrobot', 'topics': json.dumps(TOPICS)}) as writer:
        for received, topic, msg, sent in sorted(log, key=lambda x: x[0]):
            writer.write(topic, serialize_message(msg), received, sent)
    return writer.path


def joint_state(problem, s: list[float], step: int) -> JointState:
    """The JointState of state s, laid out per the problem's state table."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * 50_000_000, 1_000_000_000)
    msg.header.frame_id = problem.ros.get('frame_id', problem.name)
    joints = list(problem.joints)
    pos, vel = [0.0] * len(joints), [0.0] * len(joints)
    for coord, value in zip(problem.state, s):
        (pos if coord.field == 'position' else vel)[joints.index(coord.joint)] = value
    msg.name, msg.position, msg.velocity, msg.effort = joints, pos, vel, [0.0] * len(joints)
    return msg


def episode(states: list[list[float]], end: str) -> dict:
    n = len(states) - 1     # one command and reward per MDP step
    commands = [(-2.0, 0.0, 2.0, 2.0)[k % 4] for k in range(n)]
    rewards = [-3.0 + 0.5 * math.sin(k) for k in range(n)]
    return {'states': states, 'commands': commands, 'rewards': rewards, 'end': end}


@pytest.fixture(scope='module')
def acrobot_file(tmp_path_factory) -> tuple[Path, list[dict]]:
    eps = [episode(acrobot_states(30)[:20], 'step_limit'), episode(acrobot_states(25), 'goal')]
    return write_recording(tmp_path_factory.mktemp('acrobot'), 'acrobot', eps), eps


def inspect_json(capsys, path: Path, *args: str) -> tuple[int, dict, str]:
    rc = cli.main(['inspect', str(path), '--json', *args])
    out, err = capsys.readouterr()
    return rc, (json.loads(out) if out.strip() else {}), err


@pytest.mark.parametrize('whole_bag', [True, False])
def test_json_gives_back_the_known_episode_numbers(capsys, acrobot_file, whole_bag):
    """--json reports each episode's return, steps, goal, delta* and action counts, from the
    bag directory or from its storage file alone."""
    path, eps = acrobot_file
    rc, summary, err = inspect_json(capsys, path.parent if whole_bag else path)
    assert rc == 0 and err == ''
    assert summary['complete'] and summary['error'] is None
    assert summary['profile'] == 'ros2' and summary['problem'] == 'acrobot'
    assert summary['bag'] is whole_bag and len(summary['storage_files']) == 1
    assert summary['message_count'] == sum(2 + len(e['states']) + 3 * len(e['rewards'])
                                           for e in eps)
    counts = {t['topic']: t['count'] for t in summary['topics']}
    assert counts['/joint_states'] == 20 + 25 and counts['/episode_event'] == 4
    got = summary['episodes']
    assert [e['episode'] for e in got] == [0, 1]
    assert [e['end'] for e in got] == ['step_limit', 'goal']
    for e, ep in zip(got, eps):
        assert e['steps'] == len(ep['rewards'])
        assert e['return'] == pytest.approx(sum(ep['rewards']))
        assert e['return_from_rewards'] == pytest.approx(sum(ep['rewards']))
        assert e['actions'] == {'-2': ep['commands'].count(-2.0),
                                '0': ep['commands'].count(0.0),
                                '2': ep['commands'].count(2.0)}
        assert e['messages'] == {'states': len(ep['states']), 'rewards': len(ep['rewards']),
                                 'commands': len(ep['commands'])}
        assert e['delta_star'] == pytest.approx(e['delta_star_from_states'])
    assert got[0]['reached_goal'] is False and got[0]['steps_to_goal'] is None
    assert got[1]['reached_goal'] is True and got[1]['steps_to_goal'] == 24
    assert got[1]['delta_star'] == 0.0 and got[1]['achieved'] is True
    assert summary['episodes_reaching_goal'] == 1


def test_stamped_commands_count_as_the_answers_to_their_states(capsys, tmp_path):
    """Commands on command_stamped (as the policy node sends them) go to the episode of the
    state they answer, with that state's stamp; late_commands comes from the end event."""
    from sapga_ros.recording.inspect import summarize

    eps = [dict(episode(acrobot_states(12), 'step_limit'), late=2),
           episode(acrobot_states(9), 'goal')]
    path = write_recording(tmp_path, 'acrobot', eps, stamped=True)
    rc, summary, err = inspect_json(capsys, path.parent)
    assert rc == 0 and err == ''
    roles = {t['topic']: t['role'] for t in summary['topics']}
    assert roles['/command_stamped'] == 'command_stamped'
    for got, ep in zip(summary['episodes'], eps):
        assert got['actions'] == {'-2': ep['commands'].count(-2.0),
                                  '0': ep['commands'].count(0.0),
                                  '2': ep['commands'].count(2.0)}
        assert got['messages']['commands'] == len(ep['commands'])
        assert got['late_commands'] == ep.get('late')
    _, episodes, _ = summarize(read_recording(path.parent))
    for ep in episodes:
        stamps, _ = ep.trajectory()
        assert [t for t, _ in ep.commands] == list(stamps[:-1])   # each its state's stamp


def test_lagging_values_between_episodes_or_short_of_one_per_state(capsys, tmp_path):
    """A recorder that falls behind: an answer published after an episode's end event (to
    its final state) and before the next start counts for neither episode; commands short
    of one per state (one lost) all count, each at the latest state heard before it; an
    event whose time overflows nanoseconds has none (the summary is still made)."""
    problem = load_problem('acrobot')
    states = acrobot_states(8)
    sent = [0]
    log: list[tuple[int, str, object, int]] = []

    def put(role: str, msg: object, lag: int) -> None:
        sent[0] += 1_000_000
        log.append((sent[0] + lag, TOPICS[role], msg, sent[0]))
    step = 0
    for number in range(3):
        put('event', String(data=json.dumps({'event': 'start', 'episode': number,
                                             'time': step * 0.05})), 1)
        for k, s in enumerate(states):
            put('state', joint_state(problem, s, step), 3_000_000)
            step += 1
            if k < 7 and not (number == 1 and k == 3):     # episode 1 loses a command
                put('command', Float64(data=(-2.0, 0.0, 2.0)[k % 3]), 6_000_000)
        end = {'event': 'step_limit', 'episode': number, 'step': 7, 'time': (step - 1) * 0.05}
        put('event', String(data=json.dumps(end)), 1)
        put('command', Float64(data=7.0), 6_000_000)        # answers the final state
    rc, summary, err = inspect_json(capsys, write_received(tmp_path / 'bag', log))
    assert rc == 0 and err == ''
    counts = [e['actions'] for e in summary['episodes']]
    assert counts[0] == counts[2] == {'-2': 3, '0': 2, '2': 2}
    assert counts[1] == {'-2': 2, '0': 2, '2': 2}
    far = write_recording(tmp_path / 'far', 'acrobot', [
        {**episode(acrobot_states(6), 'step_limit'), 'end_fields': {'time': 1e300}}])
    rc, summary, err = inspect_json(capsys, far.parent)
    assert rc == 0 and err == '' and summary['episodes'][0]['messages']['states'] == 6


def test_publish_times_left_0_by_a_writer_are_receive_times(capsys, tmp_path, acrobot_file):
    """A writer that leaves publish_time 0 (not known): values go to their episode by receive
    time, the same summary as with publish times."""
    path, eps = acrobot_file
    zero = write_recording(tmp_path, 'acrobot', eps, sent=False, stray=True)
    _, want, _ = inspect_json(capsys, path.parent)
    rc, got, err = inspect_json(capsys, zero.parent)
    assert rc == 0 and got['episodes'] == want['episodes']
    assert [e['messages']['rewards'] for e in got['episodes']] == [len(e['rewards'])
                                                                   for e in eps]


def test_the_hold_measures_come_from_the_end_event_when_it_carries_them(capsys, tmp_path):
    """The simulator's end event carries the hold measures of the true state (the recorded
    states carry sensor noise, or a robot's own joint convention): inspect reports them;
    an event without them, or with values the simulator never writes, gets them from the
    recorded states, without a traceback."""
    states = acrobot_states(30)
    told = {'first_entry_step': 7, 'hold_fraction': 0.75, 'rail_contacts': 2}
    bad = [{'first_entry_step': '7', 'hold_fraction': 0.5, 'rail_contacts': 0},
           {'first_entry_step': 7, 'hold_fraction': float('nan'), 'rail_contacts': 0},
           {'first_entry_step': 7, 'hold_fraction': '0.5', 'rail_contacts': 0},
           {'first_entry_step': True, 'hold_fraction': 0.5, 'rail_contacts': 0},
           {'first_entry_step': 7, 'hold_fraction': 1.5, 'rail_contacts': 0},
           {'first_entry_step': 7, 'hold_fraction': 0.5, 'rail_contacts': -1},
           {'first_entry_step': 7, 'hold_fraction': 0.5}]
    eps = [{**episode(states, 'step_limit'), 'end_fields': f} for f in [told, {}, *bad]]
    path = write_recording(tmp_path, 'acrobot', eps)
    rc, got, err = inspect_json(capsys, path.parent)
    assert rc == 0 and 'Traceback' not in err
    measures = [{k: e[k] for k in told} for e in got['episodes']]
    assert measures[0] == told
    from_states = measures[1]
    assert from_states != told and all(m == from_states for m in measures[2:])


def test_text_summary_names_topics_and_episodes(capsys, acrobot_file):
    """The text summary lists the topics and says which episode reached the goal."""
    path, _ = acrobot_file
    assert run_inspect(str(path.parent)) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'bag:       {path.parent} (rosbag2 bag, 1 storage file(s)')
    assert '/joint_states' in out and 'sensor_msgs/msg/JointState' in out
    assert 'not reached' in out and 'goal' in out


@pytest.mark.parametrize('problem_name', ['acrobot', 'pdip'])
def test_plot_writes_a_png(capsys, tmp_path, problem_name):
    """--plot draws a non-empty PNG for the acrobot and the PDIP."""
    states = acrobot_states(30) if problem_name == 'acrobot' else pdip_states(30)
    path = write_recording(tmp_path, problem_name, [episode(states, 'step_limit')])
    png = tmp_path / 'episode.png'
    rc, summary, err = inspect_json(capsys, path.parent, '--plot', str(png))
    assert rc == 0, err
    data = png.read_bytes()
    assert data.startswith(b'\x89PNG\r\n\x1a\n') and len(data) > 10_000
    assert summary['plot']['episode'] == 0


def test_truncated_file_gives_a_partial_summary(capsys, tmp_path, acrobot_file):
    """A file cut mid-way is summarised up to its last complete chunk, with one warning."""
    path, _ = acrobot_file
    data = path.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:int(len(data) * 0.6)])
    rc, summary, err = inspect_json(capsys, cut)
    assert rc == 0
    assert summary['complete'] is False and 'truncated' in summary['error']
    assert 0 < summary['message_count'] < len(read_recording(path).messages)
    assert err.count('\n') == 1 and err.startswith('warning: ') and str(cut) in err
    assert summary['episodes'][0]['episode'] == 0


@pytest.mark.parametrize('content, what', [
    (b'', 'empty'),
    (b'this is not an mcap file at all', 'not an MCAP file'),
    (b'\x89MCAP0\r\n\x01\x10', 'truncated'),
])
def test_unreadable_file_gives_a_one_line_error(capsys, tmp_path, content, what):
    """Files that hold no readable MCAP give exit status 2 and one line naming the file."""
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(content)
    rc = run_inspect(str(bad), json_out=True)
    out, err = capsys.readouterr()
    assert rc == 2 and out == ''
    assert err.count('\n') == 1 and err.startswith('sapga inspect: error: ') and str(bad) in err
    assert what in err


@pytest.mark.parametrize('make, what', [
    (lambda p: None, 'no such file'),
    (lambda p: p.mkdir(), 'neither metadata.yaml nor .mcap files'),
    (lambda p: os.mkfifo(p), 'a FIFO, not a regular file'),
])
def test_missing_or_odd_paths_give_a_one_line_error(capsys, tmp_path, make, what):
    """A missing path, an empty directory or a FIFO is named in a one-line error, exit 2
    (a FIFO would otherwise block the reader until some writer appears)."""
    path = tmp_path / 'odd.mcap'
    make(path)
    assert cli.main(['inspect', str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and str(path) in err and what in err, err


def test_corrupt_chunk_never_gives_a_traceback(capsys, tmp_path, acrobot_file):
    """Bytes flipped inside the data give a summary or a clear error, not a traceback."""
    path, _ = acrobot_file
    data = bytearray(path.read_bytes())
    for i in range(len(data) // 2, len(data) // 2 + 40):
        data[i] ^= 0xFF
    bad = tmp_path / 'flipped.mcap'
    bad.write_bytes(bytes(data))
    rc = run_inspect(str(bad), json_out=True)
    out, err = capsys.readouterr()
    assert rc in (0, 2) and 'Traceback' not in err and err.count('\n') == 1
    if rc == 0:
        summary = json.loads(out)
        assert summary['complete'] is False and summary['error']


def test_problem_comes_from_frame_id_without_metadata(capsys, tmp_path):
    """Without the sapga metadata the problem is found from the JointState frame_id."""
    path = write_recording(tmp_path, 'pdip', [episode(pdip_states(10), 'step_limit')],
                           metadata=False)
    rc, summary, _ = inspect_json(capsys, path.parent)
    assert rc == 0 and summary['problem'] == 'pdip'
    assert summary['episodes'][0]['steps'] == 9
    assert summary['episodes'][0]['delta_star_from_states'] is not None


def test_states_go_to_their_episode_by_sim_time(capsys, tmp_path):
    """A final state heard after its end event, or a first state before its start event,
    still counts in its own episode (events carry the sim time of their state)."""
    problem = load_problem('acrobot')
    states = acrobot_states(5)
    order = [('event', {'event': 'start', 'episode': 1, 'time': 0.0}),
             ('state', 0), ('state', 1), ('state', 2), ('state', 3),
             ('event', {'event': 'goal', 'episode': 1, 'step': 4, 'return': -8.0,
                        'time': 0.2}),
             ('state', 4),          # the goal state, heard after the goal event
             ('state', 5),          # the next episode's first state, before its start event
             ('event', {'event': 'start', 'episode': 2, 'time': 0.25}),
             ('state', 6),
             ('event', {'event': 'step_limit', 'episode': 2, 'step': 1, 'time': 0.3})]
    with new_bag(tmp_path / 'bag', {'problem': 'acrobot', 'topics': json.dumps(TOPICS)}
                 ) as writer:
        for t, (role, item) in enumerate(order, start=1):
            msg = (String(data=json.dumps(item)) if role == 'event'
                   else joint_state(problem, states[min(item, 4)], item))
            writer.write(TOPICS[role], serialize_message(msg), t, t)
    rc, summary, _ = inspect_json(capsys, writer.path)
    first, second = summary['episodes']
    assert rc == 0 and first['episode'] == 1 and second['episode'] == 2
    assert first['messages']['states'] == 5 and second['messages']['states'] == 2
    assert first['delta_star_from_states'] == 0.0     # the late goal state was counted


@pytest.mark.parametrize('problem_name', ['acrobot', 'pdip'])
@pytest.mark.parametrize('engine', ['mujoco', None, 'kernel'])
def test_a_recording_on_the_mujoco_robot_reads_as_the_problem(capsys, tmp_path, problem_name,
                                                              engine):
    """The MuJoCo robot publishes its own joints (its names, zero hanging down, its
    directions) and takes effort arrays: when the episode events say engine mujoco, or say
    nothing and the recording holds an effort array, inspect reads its states and commands
    as the problem's (delta* from states, actions); events saying engine kernel: not."""
    from std_msgs.msg import Float64MultiArray
    from sim_nodes.mujoco_plant import mapping

    problem = load_problem(problem_name)
    joints = mapping(problem)
    states = (acrobot_states if problem_name == 'acrobot' else pdip_states)(12)
    torques = [(-2.0, 0.0, 2.0)[k % 3] * problem.actions[-1] / 2.0 for k in range(11)]
    robot_names = [joints[j].robot_joint for j in problem.joints]

    def robot_state(s: list[float], step: int) -> JointState:
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * 50_000_000,
                                                                1_000_000_000)
        pos, vel = [0.0] * len(robot_names), [0.0] * len(robot_names)
        for c, x in zip(problem.state, s):
            m = joints[c.joint]
            k = robot_names.index(m.robot_joint)
            if c.field == 'position':
                pos[k] = (x - m.offset) * m.direction
            else:
                vel[k] = x * m.direction
        msg.name, msg.position, msg.velocity = robot_names, pos, vel
        return msg

    topics = {**TOPICS, 'effort': '/effort_controller/commands'}
    tag = {} if engine is None else {'engine': engine}
    t = [0]
    with BagWriter(tmp_path / 'bag', chunk_size=1024,
                   custom_data={'problem': problem_name, 'topics': json.dumps(TOPICS)}) as w:
        w.add_topic(TopicInfo(TOPICS['state'], ROLE_TYPES['state'], [qos_profile()]))
        w.add_topic(TopicInfo(TOPICS['event'], ROLE_TYPES['event'], [qos_profile()]))
        w.add_topic(TopicInfo(topics['effort'], 'std_msgs/msg/Float64MultiArray',
                              [qos_profile()]))

        def put(topic: str, msg: object) -> None:
            t[0] += 1
            w.write(topic, serialize_message(msg), t[0], t[0])
        put(TOPICS['event'], String(data=json.dumps({'event': 'start', 'episode': 1,
                                                     'time': 0.0, **tag})))
        for k, s in enumerate(states):
            put(TOPICS['state'], robot_state(s, k))
            if k < len(torques):
                effort = torques[k] * joints[problem.actuator_joint].direction
                put(topics['effort'], Float64MultiArray(data=[effort]))
        put(TOPICS['event'], String(data=json.dumps({'event': 'step_limit', 'episode': 1,
                                                     'step': 11, 'time': 0.55, **tag})))
    rc, summary, err = inspect_json(capsys, w.path)
    assert rc == 0 and err == ''
    got = summary['episodes'][0]
    roles = {x['topic']: x['role'] for x in summary['topics']}
    assert roles[topics['effort']] == 'effort'
    want = min(delta_of(problem, s) for s in states)
    if engine == 'kernel':                   # read as the problem's own joints: not these
        assert summary['robot_joints'] is False and got['actions'] == {}
        assert got['delta_star_from_states'] != pytest.approx(want)
        return
    assert summary['robot_joints'] is True
    assert got['delta_star_from_states'] == pytest.approx(want, abs=1e-12)
    assert got['actions'] == {f'{v:g}': torques.count(v) for v in sorted(set(torques))}
    assert got['messages']['commands'] == len(torques)
    rc = run_inspect(str(w.path))
    assert rc == 0 and "the MuJoCo robot's joints" in capsys.readouterr().out


def test_values_received_after_their_end_event_count_for_their_episode(capsys, tmp_path):
    """A recorder that falls behind takes a run's few episode events from their queue long
    before the values queued beside them, so its receive times put an episode's end event
    before most of its rewards, commands and exemplar indices.  They were published before
    it (the publishers' clock): each counts for its episode, the answer to an episode's
    final state for none, and a value published between episodes for none."""
    problem = load_problem('acrobot')
    eps = [episode(acrobot_states(12), 'step_limit'), episode(acrobot_states(9), 'goal')]
    sent = [0]                  # the publishers' clock [ns]
    log: list[tuple[int, str, object, int]] = []      # (receive time, topic, msg, sent)
    lag = 10 ** 9               # the values wait a second in the recorder's queues
    step = 0

    def put(role: str, msg: object, late: bool) -> None:
        sent[0] += 1_000_000
        log.append((sent[0] + (lag if late else 1000), TOPICS[role], msg, sent[0]))
    for number, ep in enumerate(eps):
        put('event', String(data=json.dumps({'event': 'start', 'episode': number,
                                             'time': step * 0.05})), False)
        for k, s in enumerate(ep['states']):
            put('state', joint_state(problem, s, step), True)
            step += 1
            if k < len(ep['commands']):
                put('reward', Float64(data=ep['rewards'][k]), True)
            put('command', Float64(data=ep['commands'][k] if k < len(ep['commands'])
                                   else 7.0), True)        # the 7: answers the final state
            put('exemplar', Int32(data=k % 5), True)
        put('event', String(data=json.dumps({'event': ep['end'], 'episode': number,
                                             'step': len(ep['rewards']),
                                             'time': (step - 1) * 0.05})), False)
        put('reward', Float64(data=100.0), True)           # between episodes: none's
    bag = write_received(tmp_path / 'bag', log)
    rc, summary, err = inspect_json(capsys, bag)
    assert rc == 0 and err == ''
    for got, ep in zip(summary['episodes'], eps):
        assert got['messages'] == {'states': len(ep['states']), 'rewards': len(ep['rewards']),
                                   'commands': len(ep['commands'])}
        assert got['return_from_rewards'] == pytest.approx(sum(ep['rewards']))
        assert got['actions'] == {f'{v:g}': ep['commands'].count(v)
                                  for v in sorted(set(ep['commands']))}
    from sapga_ros.recording.inspect import summarize
    _, episodes, _ = summarize(read_recording(bag))
    for got, ep in zip(episodes, eps):      # each command at the state it answered
        stamps, _ = got.trajectory()
        assert got.commands == list(zip(stamps[:-1], ep['commands']))


def test_every_truncation_point_gives_a_summary_or_one_line_error(capsys, tmp_path,
                                                                  acrobot_file):
    """Cut anywhere, a recording gives exit 0 with a partial summary or 2 with one line."""
    path, _ = acrobot_file
    data = path.read_bytes()
    cut = tmp_path / 'cut.mcap'
    counts = []
    for n in list(range(0, len(data), max(len(data) // 60, 1))) + [len(data) - 1]:
        cut.write_bytes(data[:n])
        rc = run_inspect(str(cut), json_out=True)
        out, err = capsys.readouterr()
        assert rc in (0, 2) and err.count('\n') == 1 and str(cut) in err, (n, err)
        if rc == 0:
            counts.append(json.loads(out)['message_count'])
    assert counts == sorted(counts) and counts[-1] > 0      # more bytes, never fewer messages
