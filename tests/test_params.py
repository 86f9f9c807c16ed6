"""One parameter vocabulary (sim_nodes/params.py and its adapters): a refused value is the
same line in the CLI, the trainer node and a parameter file; integers are accepted for
double parameters over DDS; a problem's default is resolved once and 0 means 0, so a
launch at delta 0 records delta 0; populations that cannot fit in memory are refused."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter

from process_helpers import sapga_in_process
from ros_helpers import isolated_ros
from sapga_ros.errors import ConfigError
from sapga_ros.policies.kinds import policy_delta
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.policy_params import PARAMETERS as POLICY_PARAMETERS
from sapga_ros.nodes.recorder_node import RecorderNode
from sapga_ros.nodes.recorder_params import PARAMETERS as RECORDER_PARAMETERS
from sapga_ros.nodes.trainer_node import TrainerNode
from sapga_ros.nodes.trainer_params import PARAMETERS as TRAINER_PARAMETERS
from sapga_ros.optim.sapga import SapgaParams, memory_problem
from sapga_ros.training.loop import TrainConfig
from sim_nodes.params import DELTA
from sim_nodes.problem import config_dir, load_problem
from sim_nodes.ros.runner import check_params_file
from sim_nodes.ros.sim_node import SimNode
from sim_nodes.ros.sim_settings import sim_parameters
from test_launch import launch, the_bag
from test_node_conventions import run

STYLES = 'state-action, via-point, state-value, state-state, state-action-value'
REFUSED = [   # (parameter, value, CLI option, YAML text, the one line)
    ('n_pop', 1, '--pop', '1', 'n_pop: expected an integer in [2, 1e6], got 1'),
    ('style', 'telepathy', '--style', 'telepathy',
     f"style: expected one of {STYLES}, got 'telepathy'"),
    ('delta', -3.0, '--delta', '-3.0', 'delta: expected a number in [0, 1e9], got -3.0'),
]


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def sapga(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """`sapga ARGS` in ``cwd``, its main called in this process (the node executables below
    run as processes; test_cli.py runs `sapga train` as one)."""
    return sapga_in_process(list(args), cwd=cwd)


def params_file(tmp_path: Path, values: dict) -> Path:
    path = tmp_path / 'trainer.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': values}}))
    return path


@pytest.mark.parametrize('name, value, option, text, line', REFUSED)
def test_a_refused_value_is_the_same_line_in_cli_node_and_params_file(
        ros, tmp_path, name, value, option, text, line):
    """A numeric and a choice parameter out of range: `sapga train`, the trainer node's
    `-p` at start, its --params-file and a set over DDS all print the declaration's line."""
    cli = sapga('train', '--problem', 'acrobot', option, text, cwd=tmp_path)
    assert cli.returncode == 2 and cli.stderr.splitlines()[-1] == f'sapga train: error: {line}'

    given = run('trainer_node', '--ros-args', '-p', f'{name}:={text}')
    assert given.returncode == 2
    assert given.stderr.strip().splitlines() == [f'trainer_node: error: {line}']

    path = params_file(tmp_path, {name: value})
    filed = run('trainer_node', '--ros-args', '--params-file', str(path))
    assert filed.returncode == 2
    assert filed.stderr.strip().splitlines() == [
        f'trainer_node: error: --params-file {path}: {line}']

    ros.start(TrainerNode)
    client = ros.start(lambda **kw: __import__('rclpy').create_node('setter', **kw))
    set_params = client.create_client(SetParameters, '/trainer_node/set_parameters')
    msg = Parameter(name, value=value).to_parameter_msg()
    result = ros.call(set_params, SetParameters.Request(parameters=[msg])).results[0]
    assert not result.successful and result.reason == line


def test_populations_that_cannot_fit_in_memory_are_refused_up_front(ros, tmp_path):
    """A million children: one line, exit 2, before anything is allocated, the same in the
    CLI, the trainer node (-p and params file) and the config dataclass."""
    line = memory_problem(100, 1_000_000, 100)
    assert line.startswith('n_pop 100 x (n_child 1000000 + 1) policies of up to l_max 100 '
                           'exemplars need')
    # a policy costs memory of its own, however few its exemplars
    assert memory_problem(1_000_000, 1, 30) is not None
    assert memory_problem(100, 10, 100) is None and memory_problem(2000, 10, 100) is None
    with pytest.raises(ConfigError) as refused:
        SapgaParams(n_child=1_000_000)
    assert str(refused.value) == line
    cli = sapga('train', '--problem', 'acrobot', '--children', '1000000', '--steps', '1000',
                cwd=tmp_path)
    assert cli.returncode == 2 and cli.stderr.splitlines() == [f'sapga train: error: {line}']
    assert not (tmp_path / 'runs').exists() or not any((tmp_path / 'runs').iterdir())
    given = run('trainer_node', '--ros-args', '-p', 'n_child:=1000000')
    assert given.returncode == 2
    assert given.stderr.strip().splitlines() == [f'trainer_node: error: {line}']
    path = params_file(tmp_path, {'n_child': 1_000_000})
    filed = run('trainer_node', '--ros-args', '--params-file', str(path))
    assert filed.returncode == 2
    assert filed.stderr.strip().splitlines() == [f'trainer_node: error: {line}']
    node = ros.start(TrainerNode)
    result = node.set_parameters([Parameter('n_child', value=1_000_000)])[0]
    assert not result.successful and result.reason == line
    assert SapgaParams(n_pop=100, n_child=10, l_max=1000)     # 10x the paper's exemplars: fine


def test_integers_are_accepted_for_double_parameters_over_dds(ros):
    """`-p delta:=0` at start and an integer in a set_parameters request over DDS are taken
    as the double they name (rclpy alone refuses both)."""
    proc = ros.spawn('acrobot_sim', '--ros-args', '-p', 'delta:=0', '-p',
                     'real_time_factor:=2', '-p', 'mode:=lockstep')
    client = ros.start(lambda **kw: __import__('rclpy').create_node('asker', **kw))
    get = client.create_client(GetParameters, '/acrobot_sim/get_parameters')
    set_params = client.create_client(SetParameters, '/acrobot_sim/set_parameters')
    got = ros.call(get, GetParameters.Request(names=['delta', 'real_time_factor'])).values
    assert [(v.type, v.double_value) for v in got] == [
        (ParameterType.PARAMETER_DOUBLE, 0.0), (ParameterType.PARAMETER_DOUBLE, 2.0)]
    request = SetParameters.Request(parameters=[ParameterMsg(
        name='republish_period', value=ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                      integer_value=1))])
    assert ros.call(set_params, request).results[0].successful
    (value,) = ros.call(get, GetParameters.Request(names=['republish_period'])).values
    assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 1.0)
    assert ros.stop(proc) == 0


@pytest.mark.parametrize('make, table', [
    (lambda ros, tmp: ros.start(SimNode), sim_parameters('acrobot')),
    (lambda ros, tmp: ros.start(PolicyNode), POLICY_PARAMETERS),
    (lambda ros, tmp: ros.start(TrainerNode), TRAINER_PARAMETERS),
])
def test_every_changeable_double_parameter_takes_an_integer(ros, tmp_path, make, table):
    """Each node's writable double parameters take an integer within their range."""
    node = make(ros, tmp_path)
    doubles = [p for p in table if p.type is float and not p.read_only]
    assert doubles
    for p in doubles:
        whole = int(max(p.bounds()[0], 1.0))
        result = node.set_parameters([Parameter(p.name, value=whole)])[0]
        assert result.successful, (p.name, result.reason)
        assert node.get_parameter(p.name).value == float(whole)


def test_integer_start_values_for_read_only_doubles_are_taken(ros, tmp_path):
    """A read-only double (the recorder's delta) given as an integer at start is its
    double; 0 is 0, not the problem's default."""
    node = ros.start(RecorderNode, params={'output_dir': str(tmp_path), 'delta': 0})
    assert node.get_parameter('delta').value == 0.0
    assert [p for p in RECORDER_PARAMETERS if p.name == 'delta'][0].from_problem


def test_the_problems_default_is_resolved_once_and_zero_means_zero():
    """Not given: the problem's; given (0 included): that value; TrainConfig refuses what no
    run can use."""
    acrobot = load_problem('acrobot')
    assert acrobot.resolve('delta') == acrobot.default_delta > 0
    assert acrobot.resolve('delta', 0) == 0.0
    assert acrobot.resolve('n_step') == acrobot.n_step
    assert TrainConfig(delta=0.0).delta == 0.0 and TrainConfig().delta is None
    for bad in (float('nan'), -3.0, float('inf')):
        with pytest.raises(ConfigError, match='delta: expected a number in'):
            TrainConfig(delta=bad)


def test_a_policys_delta_is_one_rule():
    """Given, else the policy's training delta if it is a delta (a boolean is not), else the
    problem's: what `sapga eval` and `sapga launch swingup` both use."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(0)

    def policy(meta: dict) -> ExemplarPolicy:
        return ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (3, 4)),
                              rng.integers(0, 3, 3), meta=meta)
    assert policy_delta(policy({'delta': 0.4})) == 0.4
    assert policy_delta(policy({'delta': 0.4}), 0.0) == 0.0
    for meta in ({'delta': True}, {'delta': -1.0}, {'delta': 'x'}, {}):
        assert policy_delta(policy(meta)) == problem.default_delta, meta


def test_every_shipped_params_file_passes_its_nodes_declarations():
    """msg_configs/params/<exe>[_<example>].yaml holds values its node's declarations accept
    (the same check a node makes of a --params-file before it starts)."""
    tables = {'policy_node': POLICY_PARAMETERS, 'recorder_node': RECORDER_PARAMETERS,
              'trainer_node': TRAINER_PARAMETERS}
    paths = sorted((config_dir() / 'params').glob('*.yaml'))
    assert len(paths) >= 4
    for path in paths:
        exe = path.stem
        table = next((tables[name] for name in tables if exe.startswith(name)), None) or \
            sim_parameters(exe.removesuffix('_sim'))    # policy_node_<robot>.yaml: examples
        check_params_file(str(path), table)
    bad = config_dir() / 'params' / 'trainer_node.yaml'
    assert DELTA.name not in yaml.safe_load(bad.read_text())['/**']['ros__parameters']


def test_a_launch_at_delta_0_records_delta_0(tmp_path):
    """`sapga launch swingup --delta 0` with a policy trained at 0.4: the simulator runs at
    0, and the bag says 0 (metadata.yaml, the MCAP file's metadata, and `sapga inspect`)."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(7)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (60, 4)),
                            rng.integers(0, 3, 60), meta={'delta': 0.4})
    policy.save(tmp_path / 'p.json')
    done = launch(['swingup', '--policy', str(tmp_path / 'p.json'), '--out',
                   str(tmp_path / 'rec'), '--delta', '0'], tmp_path)
    assert 'delta 0.0' in done.stdout
    bag = the_bag(tmp_path / 'rec')
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['custom_data']['delta'] == '0.0'
    (mcap_path,) = bag.glob('*.mcap')
    with open(mcap_path, 'rb') as f:
        records = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert any(m.get('delta') == '0.0' for m in records.values()), records
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    inspected = subprocess.run([sys.executable, '-m', 'sapga_ros.cli.main', 'inspect',
                                str(bag), '--json'], capture_output=True, text=True,
                               timeout=120, env=env)
    summary = json.loads(inspected.stdout)
    assert summary['goal_delta'] == 0.0
    assert [(e['end'], e['goal_delta']) for e in summary['episodes']] == [('step_limit', 0.0)]
