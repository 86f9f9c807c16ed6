"""ROS conventions of the node executables: --help from the parameter tables, declared ranges
read over the describe_parameters service, and one-line exit-2 errors for bad ROS arguments
(sim_nodes/ros/params.py, sim_nodes/ros/runner.py)."""
from __future__ import annotations

import contextlib
import io
import os
import subprocess
from importlib.metadata import entry_points
from pathlib import Path

import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters

from ros_helpers import isolated_ros
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.policy_params import PARAMETERS as POLICY_PARAMETERS
from sapga_ros.nodes.recorder_node import RecorderNode
from sapga_ros.nodes.recorder_params import PARAMETERS as RECORDER_PARAMETERS
from sim_nodes.models import MODELS
from sim_nodes.models.registry import sim_executable
from sim_nodes.ros.sim_node import SimNode
from sim_nodes.ros.sim_settings import sim_parameters
from test_executables import ros2_run_path

SIMS = sorted(sim_executable(m) for m in MODELS)
EXECUTABLES = [*SIMS, 'sim_node', 'policy_node', 'recorder_node', 'trainer_node']
NUMERIC = (ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_DOUBLE)
RCLPY_OWN = {'use_sim_time', 'start_type_description_service'}  # every rclpy node's
TIMEOUT = 120  # [s] for one short run of an executable on a loaded machine


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def run(exe: str, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([str(ros2_run_path(exe)), *args], capture_output=True, text=True,
                          timeout=TIMEOUT, env=env)


def help_in_process(exe: str, flag: str) -> str:
    """What ``<exe> FLAG`` prints, from the executable's console-script entry point called
    in this process (the help path returns before rclpy starts); the output."""
    (point,) = [e for e in entry_points(group='console_scripts') if e.name == exe]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert point.load()([exe, flag]) == 0
    return out.getvalue()


def help_table(text: str) -> dict[str, dict[str, str]]:
    """The parameter table of a --help text: name -> its cells, by the header's columns."""
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.split()[:2] == ['name', 'type'])
    header = lines[k]
    names = ['name', 'type', 'default', 'range / choices', 'description']
    starts = [header.index(n) for n in names] + [None]
    table = {}
    for line in lines[k + 1:]:
        if not line.strip():
            break
        cells = {n: line[starts[j]:starts[j + 1]].strip() for j, n in enumerate(names)}
        table[cells['name']] = cells
    return table


def make_node(exe: str, ros, tmp_path: Path):
    """The node an executable runs, made in process (its parameters as declared)."""
    if exe in SIMS or exe == 'sim_node':
        model = exe.removesuffix('_sim') if exe != 'sim_node' else 'acrobot'
        return ros.start(SimNode, default_problem=model, node_name=exe)
    if exe == 'policy_node':
        return ros.start(PolicyNode)
    if exe == 'recorder_node':
        return ros.start(RecorderNode, params={'output_dir': str(tmp_path)})
    from sapga_ros.nodes.trainer_node import TrainerNode
    return ros.start(TrainerNode)


@pytest.mark.parametrize('exe', EXECUTABLES)
def test_help_prints_every_declared_parameter_with_its_range_and_exits_0(ros, tmp_path, exe):
    """`<exe> --help` and `-h` print a usage whose table has exactly the parameters the node
    declares, each with its declared type and range, and exit 0 without starting a node
    (--help through the executable, -h through its entry point in this process)."""
    done = run(exe, '--help')
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'usage: ros2 run sapga_ros {exe} [-h] [--ros-args')
    assert '[INFO]' not in done.stdout + done.stderr          # no node started
    outputs = [done.stdout, help_in_process(exe, '-h')]
    assert outputs[0] == outputs[1]
    table = help_table(outputs[0])
    node = make_node(exe, ros, tmp_path)
    declared = set(node.get_parameters_by_prefix('')) - RCLPY_OWN
    assert set(table) == declared
    types = {ParameterType.PARAMETER_BOOL: 'boolean', ParameterType.PARAMETER_INTEGER:
             'integer', ParameterType.PARAMETER_DOUBLE: 'double', ParameterType.PARAMETER_STRING:
             'string', ParameterType.PARAMETER_STRING_ARRAY: 'string array',
             ParameterType.PARAMETER_DOUBLE_ARRAY: 'double array'}
    for name, cells in table.items():
        d = node.describe_parameter(name)
        assert cells['range / choices'] == range_text(d), name
        if not d.dynamic_typing:
            assert cells['type'] == types[d.type], name
        assert cells['description'].startswith(d.description[:40]), name


def test_a_help_inside_ros_args_is_not_the_executables(tmp_path):
    """--help after --ros-args belongs to ROS: rcl refuses it in one line, exit 2."""
    done = run('policy_node', '--ros-args', '--help')
    lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
    assert done.returncode == 2 and 'usage:' not in done.stdout
    assert len(lines) == 1 and lines[0].startswith('policy_node: error: '), lines


def range_text(d) -> str:
    """A descriptor's range as --help writes it, read independently of the declarations:
    '[low, high]' (integers whole; 1e9 for powers of ten from 1e7), the choices, or ''."""
    def number(x: float) -> str:
        if not float(x).is_integer():
            return f'{x:g}'
        digits = str(abs(int(x)))
        return f'1e{len(digits) - 1}' if len(digits) > 6 and digits.strip('0') == '1' \
            else str(int(x))
    ranges = list(d.integer_range) + list(d.floating_point_range)
    if ranges:
        return f'[{number(ranges[0].from_value)}, {number(ranges[0].to_value)}]'
    return d.additional_constraints.removeprefix('one of: ')


def describe(ros, client_node, node_name: str, names: list[str]) -> dict:
    client = client_node.create_client(DescribeParameters, f'/{node_name}/describe_parameters')
    response = ros.call(client, DescribeParameters.Request(names=names))
    return dict(zip(names, response.descriptors))


def test_numeric_parameters_declare_their_ranges_over_describe_parameters(ros, tmp_path):
    """Over DDS, every numeric parameter of the sim, policy and recorder nodes describes its
    range as the table says; choices, descriptions and read-only flags come along."""
    tables = {'sim': sim_parameters('acrobot'), 'policy_node': POLICY_PARAMETERS,
              'recorder_node': RECORDER_PARAMETERS}
    ros.start(SimNode)
    ros.start(PolicyNode)
    ros.start(RecorderNode, params={'output_dir': str(tmp_path)})
    client_node = ros.start(lambda **kw: __import__('rclpy').create_node('describer', **kw))
    for node_name, table in tables.items():
        got = describe(ros, client_node, node_name, [p.name for p in table])
        for p in table:
            d = got[p.name]
            assert d.name == p.name and d.description == p.text, p.name
            assert d.read_only == p.read_only, p.name
            if d.type in NUMERIC:
                ranges = list(d.integer_range) + list(d.floating_point_range)
                assert len(ranges) == 1, f'{node_name} {p.name}: no range declared'
                assert (ranges[0].from_value, ranges[0].to_value) == p.bounds()
            if p.choices:
                assert d.additional_constraints == f'one of: {", ".join(p.choices)}'
    numeric = [p for table in tables.values() for p in table if p.type in (int, float)]
    assert len(numeric) == 22 and all(p.low is not None for p in numeric)


def test_a_value_outside_the_declared_range_is_refused_on_set(ros):
    """rclpy enforces the declared range: setting real_time_factor to 0 is refused."""
    from rclpy.parameter import Parameter
    sim = ros.start(SimNode)
    result = sim.set_parameters([Parameter('real_time_factor', value=0.0)])[0]
    assert not result.successful and 'real_time_factor' in result.reason
    assert sim.settings.real_time_factor == 1.0


BAD_YAML = 'a: [\n'
TYPED = {'acrobot_sim': 'real_time_factor:=abc', 'policy_node': 'load_timeout:=abc',
         'recorder_node': 'queue_depth:=abc', 'trainer_node': 'steps:=abc'}


def bad_params_file(tmp_path: Path, case: str) -> Path:
    path = tmp_path / f'{case}.yaml'
    if case == 'malformed':
        path.write_text(BAD_YAML)
    elif case == 'fifo':
        os.mkfifo(path)
    elif case == 'not_a_mapping':
        path.write_text('- 1\n- 2\n')
    return path                     # 'missing': not made


@pytest.mark.parametrize('exe', sorted(TYPED))
@pytest.mark.parametrize('case', ['missing', 'malformed', 'fifo', 'not_a_mapping', 'typed'])
def test_bad_params_files_and_wrongly_typed_overrides_give_one_line_and_exit_2(
        tmp_path, exe, case):
    """A missing, malformed, FIFO or non-mapping --params-file, or a -p override of the wrong
    type: one line naming the file or parameter, exit 2, no traceback."""
    if case == 'typed':
        args, named = ['-p', TYPED[exe]], TYPED[exe].split(':=')[0]
    else:
        path = bad_params_file(tmp_path, case)
        args, named = ['--params-file', str(path)], str(path)
    if exe == 'recorder_node':
        args += ['-p', f'output_dir:={tmp_path}']
    done = run(exe, '--ros-args', *args)
    text = done.stdout + done.stderr
    lines = [line for line in text.splitlines() if line.strip()]
    assert done.returncode == 2 and 'Traceback' not in text, text
    assert len(lines) == 1 and lines[0].startswith(f'{exe}: error: '), lines
    assert named in lines[0], lines


@pytest.mark.parametrize('exe,args,words', [
    ('sim_node', ['-p', 'engine:=mujoco', '-p', 'effort_topic:=/joint_states'],
     'ros.topics.state (JointState) and effort_topic (Float64MultiArray)'),
    ('sim_node', ['-r', 'command:=joint_states'],
     'ros.topics.state (JointState) and ros.topics.command (Float64)'),
    ('acrobot_sim', ['-r', 'reward:=/clock'], 'ros.topics.reward (Float64) and the clock'),
    ('policy_node', ['-p', 'command_output:=effort_array', '-p', 'effort_topic:=markers'],
     'ros.topics.markers (MarkerArray) and effort_topic (Float64MultiArray)'),
    ('policy_node', ['-r', 'exemplar_index:=joint_states'],
     'ros.topics.exemplar (Int32) and ros.topics.state (JointState)'),
])
def test_two_topics_of_one_node_on_one_name_are_one_line_and_exit_2(exe, args, words):
    """A topic parameter or a remapping that puts two of a node's topics of different types
    on one name: one line naming both, exit 2, before rcl is asked (a subscription it
    refused printed rcutils' error log and 'invalid allocator')."""
    done = run(exe, '--ros-args', '-p', 'problem:=acrobot', *args)
    text = done.stdout + done.stderr
    lines = [line for line in text.splitlines() if line.strip()]
    assert done.returncode == 2 and 'Traceback' not in text and 'rcutils' not in text, text
    assert len(lines) == 1 and lines[0].startswith(f'{exe}: error: '), lines
    assert words in lines[0], lines


def test_rcl_refusals_of_ros_args_are_one_line_without_rcl_log(tmp_path):
    """A params file PyYAML reads but rcl refuses (mixed array), and a malformed -p rule:
    one line each, exit 2, rcl's own log line and traceback dropped."""
    mixed = tmp_path / 'mixed.yaml'
    mixed.write_text('/**:\n  ros__parameters:\n    a: [1, "x"]\n')
    for args, named in ((['--params-file', str(mixed)], str(mixed)), (['-p', 'foo'], "'-p foo'")):
        done = run('pendulum_sim', '--ros-args', *args)
        text = done.stdout + done.stderr
        lines = [line for line in text.splitlines() if line.strip()]
        assert done.returncode == 2 and 'Traceback' not in text and '[rcl]' not in text, text
        assert len(lines) == 1 and named in lines[0], lines


def test_every_node_executable_but_the_generic_sim_ships_a_params_file():
    """share/sapga_ros/params/<exe>.yaml exists (as installed from msg_configs/params) for
    every node executable, and names only parameters the node declares."""
    import yaml
    from ament_index_python.packages import get_package_share_directory
    share = Path(get_package_share_directory('sapga_ros')) / 'params'
    tables = {**{exe: sim_parameters(exe.removesuffix('_sim')) for exe in SIMS},
              'policy_node': POLICY_PARAMETERS, 'recorder_node': RECORDER_PARAMETERS}
    for exe in [*SIMS, 'policy_node', 'recorder_node', 'trainer_node']:
        path = share / f'{exe}.yaml'
        assert path.is_file(), path
        if exe in tables:
            given = yaml.safe_load(path.read_text())['/**']['ros__parameters']
            assert set(given) <= {p.name for p in tables[exe]}, exe


def test_the_trainer_refuses_a_bad_start_in_one_line_and_exit_2(tmp_path):
    """A start-up run it cannot train (train_on_start) and a policy_file it cannot serve
    each stop the trainer with the reason as its only line (no 'ready' before it), exit 2."""
    for args, words in (
            (('-p', 'train_on_start:=true', '-p', 'method:=ql', '-p', 'delay:=1'),
             'cannot train'),
            (('-p', f'policy_file:={tmp_path / "missing.json"}'), 'missing.json')):
        done = run('trainer_node', '--ros-args', '-p', 'problem:=acrobot',
                   '-p', f'out:={tmp_path / "p.json"}', *args)
        lines = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
        assert done.returncode == 2 and len(lines) == 1 and words in lines[0], lines
        assert 'Traceback' not in lines[0]
