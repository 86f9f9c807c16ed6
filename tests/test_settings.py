"""Settings written once (sim_nodes/params.py): the config dataclasses' defaults are what
``sapga train`` offers, what the trainer node declares and what its parameter file lists;
bounds and choices are enforced alike on every side."""
from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter

from ros_helpers import isolated_ros
from sapga_ros.cli.main import build_parser
from sapga_ros.cli.train import train_config
from sapga_ros.errors import ConfigError
from sapga_ros.policies.styles import STYLES
from sapga_ros.nodes.trainer_node import TrainerNode
from sapga_ros.nodes.trainer_params import PARAMETERS, NodeSettings
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train_sapga
from sim_nodes.problem import config_dir, load_problem

RUN = (TrainConfig, SapgaParams, QlParams)


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


def _yaml() -> dict:
    path = config_dir() / 'params' / 'trainer_node.yaml'
    return yaml.safe_load(path.read_text())['/**']['ros__parameters']


def _defaults(*classes) -> dict:
    """name -> the field's default (None: the problem's) of every declared parameter."""
    return {f.name: f.default for cls in classes for f in fields(cls) if 'param' in f.metadata}


def test_cli_defaults_are_the_dataclass_defaults():
    """`sapga train` with no options describes the default TrainConfig, field by field."""
    args = build_parser().parse_args(['train', '--problem', 'acrobot'])
    for name, default in _defaults(*RUN).items():
        assert getattr(args, name) == default, name
    assert train_config(args, 'acrobot') == TrainConfig(problem='acrobot')


def test_cli_options_set_every_setting():
    """Each generated option reaches its field (flags: --pop, --children, ..., --style)."""
    args = build_parser().parse_args([
        'train', '--problem', 'pdip', '--method', 'ql', '--steps', '1e6', '--seed', '3',
        '--jobs', '2', '--checkpoint-every', '5', '--resume', '--pop', '20', '--children', '4',
        '--l-min', '10', '--l-max', '20', '--style', 'via-point', '--chunk-steps', '5000'])
    config = train_config(args, 'pdip')
    assert config == TrainConfig(
        problem='pdip', method='ql', steps=1_000_000, seed=3, jobs=2, checkpoint_every=5,
        resume=True, params=SapgaParams(n_pop=20, n_child=4, l_min=10, l_max=20,
                                        style='via-point'), ql=QlParams(chunk_steps=5000))


@pytest.mark.parametrize('argv, needle', [
    (['--pop', '1'], 'n_pop: expected an integer in [2, 1e6], got 1'),
    (['--chunk-steps', '10'], 'chunk_steps: expected an integer in [1000, 1e7], got 10'),
    (['--seed', '-1'], 'seed: expected an integer >= 0, got -1'),
    (['--style', 'telepathy'], 'style: expected one of state-action, via-point, '
                               "state-value, state-state, state-action-value, got 'telepathy'"),
    (['--delta', '-3'], 'delta: expected a number in [0, 1e9], got -3.0'),
])
def test_cli_refuses_values_outside_the_bounds(argv, needle, capsys):
    """A value outside a field's bounds is a usage error: its last line is the
    declaration's one line."""
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(['train', '--problem', 'acrobot', *argv])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.splitlines()[-1] == f'sapga train: error: {needle}'


def test_dataclasses_refuse_values_outside_the_bounds():
    """Constructing a config out of bounds is a ConfigError naming the field."""
    for make, name in [(lambda: TrainConfig(steps=0), 'steps'),
                       (lambda: TrainConfig(method='ppo'), 'method'),
                       (lambda: TrainConfig(delta=math.nan), 'delta'),
                       (lambda: TrainConfig(delta=-3.0), 'delta'),
                       (lambda: TrainConfig(delta=True), 'delta'),
                       (lambda: SapgaParams(n_pop=1), 'n_pop'),
                       (lambda: SapgaParams(style='telepathy'), 'style'),
                       (lambda: SapgaParams(l_min=30, l_max=20), 'l_min'),
                       (lambda: QlParams(chunk_steps=10**9), 'chunk_steps')]:
        with pytest.raises(ConfigError, match=name):
            make()


def test_parameter_file_lists_every_parameter_with_its_default():
    """msg_configs/params/trainer_node.yaml holds each declared parameter at the default the
    dataclasses give (and problem, checkpoint at the node's own defaults); delta, the
    problem's unless given, is not listed."""
    listed = _yaml()
    declared = {p.name: p.default for p in PARAMETERS if not p.from_problem}
    assert set(listed) == set(declared)
    assert {p.name for p in PARAMETERS if p.from_problem} == {'delta'}
    for name, default in declared.items():
        assert listed[name] == default, name
    assert {k: declared[k] for k in _defaults(*RUN, NodeSettings) if k != 'delta'} == \
        {k: v for k, v in _defaults(*RUN, NodeSettings).items() if k != 'delta'}


def test_node_declares_the_dataclass_defaults_with_ranges(ros):
    """A trainer node without overrides has every setting at its dataclass default, the
    bounds as descriptor ranges and the choices named; its config is the default one."""
    node = ros.start(TrainerNode)
    for name, default in _defaults(*RUN, NodeSettings).items():
        expected = load_problem('acrobot').default_delta if name == 'delta' else default
        assert node.get_parameter(name).value == expected, name
    for name, value in _yaml().items():
        assert node.get_parameter(name).value == value, name
    n_pop = node.describe_parameter('n_pop')
    assert (n_pop.integer_range[0].from_value, n_pop.integer_range[0].to_value) == \
        (2, 1_000_000)
    assert 'N_pop' in n_pop.description
    assert all(s in node.describe_parameter('style').additional_constraints for s in STYLES)
    period = node.describe_parameter('log_period').floating_point_range[0]
    assert (period.from_value, period.to_value) == (1e-3, 3600.0)
    config = node.train_config()
    assert config == TrainConfig(problem='acrobot', delta=load_problem('acrobot').default_delta)


def test_node_style_is_validated_and_applies_to_the_next_run(ros):
    """style takes any known style between runs; an unknown one, or a value outside a
    range, is refused with the parameter named; a bad start value is a ConfigError."""
    node = ros.start(TrainerNode, params={'style': 'state-value'})
    assert node.train_config().params.style == 'state-value'
    assert node.set_parameters([Parameter('style', value='via-point')])[0].successful
    assert node.train_config().params.style == 'via-point'
    for name, value in [('style', 'telepathy'), ('n_pop', 1), ('chunk_steps', 10),
                        ('log_period', math.nan), ('method', 'ppo')]:
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and name in result.reason, (name, result.reason)
    with pytest.raises(ConfigError, match='style'):
        ros.start(TrainerNode, params={'style': 'telepathy'}, node_name='bad_style')
    with pytest.raises(ConfigError, match='n_pop'):
        ros.start(TrainerNode, params={'n_pop': 1}, node_name='bad_pop')


def test_node_trains_the_style_it_is_given_as_the_offline_loop_does(ros):
    """A run with style via-point is what the one training loop gives offline, bit for bit."""
    small = {'n_pop': 6, 'n_child': 2, 'l_min': 4, 'l_max': 8, 'jobs': 1, 'seed': 2,
             'delta': 0.3, 'steps': 30_000, 'style': 'via-point'}
    node = ros.start(TrainerNode, params={**small, 'train_on_start': True})
    ros.wait_for(lambda: node.status()['state'] == 'done', 'the run to finish', timeout=60)
    served = node._served.policy
    offline = train_sapga(node.train_config()).policy
    assert served.style == offline.style == 'via-point'
    assert np.array_equal(served.states, offline.states)
    assert served.meta['value'] == offline.meta['value']
