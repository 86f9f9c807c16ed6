"""Problem configuration (sim_nodes/problem.py, msg_configs/*.yaml; SPEC 1, 2): every shipped
file loads and says what SPEC 2 says, numbers as multiples of pi parse without evaluation,
and bad files give a one-line ConfigError naming the file and the field."""
from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Callable

import pytest
import yaml

from sapga_ros.errors import ConfigError, UnknownProblemError
from sim_nodes.problem import (MAX_CONFIG_BYTES, config_dir, load_problem, load_problem_file,
                               parse_number, problem_names)

PI = math.pi
SHIPPED = sorted(config_dir().glob('*.yaml'))


@pytest.fixture(scope='module')
def acrobot_doc() -> dict:
    """msg_configs/acrobot.yaml as parsed YAML, to edit into bad variants."""
    return yaml.safe_load((config_dir() / 'acrobot.yaml').read_text(encoding='utf-8'))


def write_yaml(tmp_path: Path, doc, name: str = 'edited.yaml') -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc), encoding='utf-8')
    return path


def assert_config_error(path: Path, *needles: str) -> ConfigError:
    """Loading ``path`` raises a one-line ConfigError naming the file and each needle."""
    with pytest.raises(ConfigError) as info:
        load_problem_file(path)
    message = str(info.value)
    assert str(path) in message, message
    for needle in needles:
        assert needle in message, message
    assert '\n' not in message
    return info.value


# --- the shipped configurations -----------------------------------------------------------

def test_msg_configs_holds_the_papers_problems():
    """The acrobot, the PDIP and pdip_single are configured."""
    assert {'acrobot', 'pdip', 'pdip_single'} <= set(problem_names())
    assert [p.stem for p in SHIPPED] == problem_names()


@pytest.mark.parametrize('path', SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_yaml_loads_consistently(path):
    """Each msg_configs/*.yaml loads, by file and by name, into a Problem whose name is the
    file's, whose initial and best states lie within the bounds, and whose model packs its
    physics."""
    problem = load_problem_file(path)
    assert problem.name == path.stem and load_problem(path.stem) == problem
    assert len(set(problem.state_names)) == problem.dim
    assert (problem.low <= problem.initial_state).all()
    assert (problem.initial_state <= problem.high).all()
    assert (problem.low <= problem.best_state).all() and (problem.best_state <= problem.high).all()
    assert len(set(problem.actions)) == len(problem.actions)
    assert problem.params().shape == (2 + len(problem.physics),)


def test_acrobot_configuration_is_spec_2_1(acrobot_problem):
    """The acrobot's YAML gives SPEC 2.1's state, ranges, start, best state, actions,
    physics and timing."""
    p = acrobot_problem
    assert p.state_names == ('theta1', 'theta2', 'theta1_dot', 'theta2_dot')
    assert list(p.is_angle) == [True, True, False, False]
    assert list(p.ranges) == pytest.approx([2 * PI, 2 * PI, 8 * PI, 18 * PI])
    assert p.initial == pytest.approx((3 * PI / 2, 0, 0, 0))
    assert p.best == pytest.approx((PI / 2, 0, 0, 0))
    assert p.actions == (-2.0, 0.0, 2.0)
    assert p.physics == pytest.approx({'m1': 1.0, 'm2': 1.0, 'l1': 1.0, 'lc1': 0.5, 'lc2': 0.5,
                                       'I1': 1.0, 'I2': 1.0, 'g': 9.8,
                                       'max_theta1_dot': 4 * PI, 'max_theta2_dot': 9 * PI})
    assert (p.dt, p.substeps, p.n_step) == (0.01, 5, 400)
    assert p.goal_scale == pytest.approx((2 * PI, 2 * PI, 8 * PI, 18 * PI))


@pytest.mark.parametrize('name, l2', [('pdip', 0.5), ('pdip_single', 1.0)])
def test_pdip_configurations_are_spec_2_2(name, l2):
    """The PDIP's YAML (and pdip_single's, with l2 = l1) gives SPEC 2.2's state, ranges,
    start, best state, actions, physics, timing and goal area."""
    p = load_problem(name)
    assert p.model == 'pdip'
    assert p.state_names == ('x', 'v', 'theta1', 'theta2', 'theta1_dot', 'theta2_dot')
    assert list(p.ranges) == pytest.approx([5.0, 32.0, 2 * PI, 2 * PI, 8 * PI, 8 * PI])
    assert p.initial == pytest.approx((0, 0, 3 * PI / 2, 3 * PI / 2, 0, 0))
    assert p.best == pytest.approx((0, 0, PI / 2, PI / 2, 0, 0))
    assert p.actions == (-40.0, 0.0, 40.0)
    assert p.physics == pytest.approx({'m0': 1.0, 'm1': 0.2, 'm2': 0.1, 'l1': 1.0, 'l2': l2,
                                       'g': 9.8, 'x_max': 2.5, 'v_max': 16.0,
                                       'theta_dot_max': 4 * PI, 'rail_penalty': -100.0})
    assert (p.dt, p.substeps, p.n_step) == (0.01, 5, 400)
    assert p.goal_fixed[0] == 2.0 and math.isnan(p.goal_scale[0])
    assert p.goal_scale[1:] == pytest.approx((16.0, 2 * PI, 2 * PI, 8 * PI, 8 * PI))


# --- numbers --------------------------------------------------------------------------------

@pytest.mark.parametrize('text, value', [
    ('3pi/2', 3 * PI / 2), ('-4pi', -4 * PI), ('2*pi', 2 * PI), ('pi', PI), ('pi/2', PI / 2),
    ('+pi', PI), ('- pi', -PI), (' 2 pi ', 2 * PI), ('0.5pi', PI / 2), ('.5pi', PI / 2),
    ('18pi', 18 * PI), ('2 * pi / 4', PI / 2), (3, 3.0), (-2.5, -2.5), (0, 0.0),
])
def test_parse_number_reads_numbers_and_multiples_of_pi(text, value):
    """parse_number reads plain numbers and k pi / d in the usual spellings, exactly as the
    float arithmetic k * pi / d gives them."""
    assert parse_number(text, 'where') == value


@pytest.mark.parametrize('text', ['pie', '--pi', 'two', '2pi3', 'pi/', '__import__("os")',
                                  'nan', 'inf', float('nan'), float('inf'), True, None, [1],
                                  {'pi': 1}, '3pi/0'])
def test_parse_number_refuses_everything_else(text):
    """Anything but a finite number or multiple of pi is a ConfigError naming where it is
    (and nothing is evaluated)."""
    with pytest.raises(ConfigError, match='^here: '):
        parse_number(text, 'here')


# --- bad files ------------------------------------------------------------------------------

def _set(*keys_value) -> Callable[[dict], None]:
    *keys, value = keys_value

    def edit(doc: dict) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        doc[keys[-1]] = value
    return edit


def _pop(*keys) -> Callable[[dict], None]:
    def edit(doc: dict) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        doc.pop(keys[-1])
    return edit


BAD_FIELDS = {
    'missing model': (_pop('model'), ['model']),
    'missing physics': (_pop('physics'), ['physics']),
    'missing episode.dt': (_pop('episode', 'dt'), ['episode', 'dt']),
    'missing state range': (_pop('state', 2, 'range'), ['state[2]', 'range']),
    'bad number in physics': (_set('physics', 'g', 'nine'), ['physics.g', 'nine']),
    'bad number in episode': (_set('episode', 'dt', '0.01s'), ['episode.dt']),
    'bad number in initial': (_set('initial', 0, 'down'), ['initial[0]']),
    'zero denominator': (_set('initial', 0, '3pi/0'), ['initial[0]']),
    'initial of wrong length': (_set('initial', [0, 0, 0]), ['initial']),
    'unknown model': (_set('model', 'cartpole'), ['model', 'cartpole']),
    'missing physics parameter': (_pop('physics', 'g'), ['physics', "'g'"]),
    'unknown physics parameter': (_set('physics', 'h', 1.0), ['physics', "'h'"]),
    'duplicate actions': (_set('actions', [1.0, 1.0]), ['actions']),
    'bad state field': (_set('state', 0, 'field', 'effort'), ['state[0]', 'field']),
    'range not positive': (_set('state', 3, 'range', 0), ['state[3]', 'range']),
    'state_indices out of range': (_set('q_learning', 'state_indices', [0, 9]),
                                   ['q_learning.state_indices']),
    'goal with scale and fixed': (_set('goal', 'fixed', [1.0, None, None, None]), ['goal']),
    'goal of wrong length': (_set('goal', 'scale', [1.0]), ['goal.scale']),
    'bad name': (_set('name', 'Acro bot'), ['name']),
    'no substeps': (_set('episode', 'substeps', 0), ['episode', 'substeps']),
}


@pytest.mark.parametrize('case', list(BAD_FIELDS))
def test_bad_fields_give_a_config_error_naming_file_and_field(case, acrobot_doc, tmp_path):
    """A YAML with a missing field, a bad number, an unknown model or an inconsistency is
    refused with a one-line ConfigError naming the file and the field."""
    edit, needles = BAD_FIELDS[case]
    doc = copy.deepcopy(acrobot_doc)
    edit(doc)
    assert_config_error(write_yaml(tmp_path, doc), *needles)


WRONG_TYPES = {
    'goal a number': _set('goal', 5),
    'episode a number': _set('episode', 3),
    'q_learning a list': _set('q_learning', [1]),
    'actuator a list': _set('actuator', ['elbow']),
    'tiles_per_dim not a number': _set('q_learning', 'tiles_per_dim', 'many'),
    'state_indices not numbers': _set('q_learning', 'state_indices', ['x']),
}


@pytest.mark.parametrize('case', list(WRONG_TYPES))
def test_sections_of_the_wrong_type_give_a_config_error(case, acrobot_doc, tmp_path):
    """A section or count of the wrong type is a ConfigError naming the file and the
    section, never an AttributeError, TypeError or ValueError."""
    doc = copy.deepcopy(acrobot_doc)
    WRONG_TYPES[case](doc)
    assert_config_error(write_yaml(tmp_path, doc), case.split()[0])


@pytest.mark.parametrize('content, needle', [
    (b'name: [unclosed\n', 'malformed YAML'),
    (b'- just\n- a list\n', 'top level'),
    (b'name: acrobot\nnote: caf\xe9\n', 'UTF-8'),
    (b'', 'top level'),
])
def test_unreadable_files_give_a_config_error(content, needle, tmp_path):
    """Malformed YAML, a top-level list, non-UTF-8 bytes and an empty file are refused."""
    path = tmp_path / 'bad.yaml'
    path.write_bytes(content)
    assert_config_error(path, needle)


def test_oversized_and_missing_files_give_a_config_error(tmp_path):
    """A file above the size limit is refused unread; a missing one names its path."""
    big = tmp_path / 'big.yaml'
    with open(big, 'wb') as f:
        f.truncate(MAX_CONFIG_BYTES + 1)
    assert_config_error(big, 'limit')
    assert_config_error(tmp_path / 'missing.yaml', 'cannot read')


@pytest.mark.parametrize('name', ['cartpole', 'Acrobot', '../msg_configs/acrobot', '', 'pdip '])
def test_unknown_problem_lists_the_known_ones(name):
    """An unknown problem name gives UnknownProblemError (a ConfigError) listing every
    configured problem."""
    with pytest.raises(UnknownProblemError) as info:
        load_problem(name)
    assert isinstance(info.value, ConfigError)
    assert all(known in str(info.value) for known in problem_names())


def test_file_name_and_problem_name_must_agree(acrobot_doc, tmp_path, monkeypatch):
    """A problem file whose name field differs from its file name is refused by
    load_problem ($SAPGA_CONFIG_DIR points at another folder of configurations)."""
    write_yaml(tmp_path, acrobot_doc, 'renamed.yaml')
    monkeypatch.setenv('SAPGA_CONFIG_DIR', str(tmp_path))
    assert problem_names() == ['renamed']
    with pytest.raises(ConfigError, match='renamed'):
        load_problem('renamed')
