"""The public policy file format sapga-policy/1 (policies/exemplar.py; SPEC 3.3): exact round
trips, and hostile or inconsistent documents refused with a one-line PolicyFileError that
names the field; plus the loading of sapga-qtable/1 documents (sapga_ros/policies/qtable.py)."""
from __future__ import annotations

import json
from typing import Callable

import numpy as np
import pytest

import sapga_ros.policies.exemplar as policy_module
from sapga_ros.errors import PolicyFileError
from sapga_ros.policies.exemplar import FORMAT, ExemplarPolicy
from sapga_ros.policies.runnable import load_policy, policy_from_json
from sapga_ros.policies.jsonfile import MAX_POLICY_BYTES, parse_json
from sapga_ros.policies.qtable import QTable, qtable_from_document
from sim_nodes.problem import load_problem

META = {'value': -1210.5, 'delta_star': 0.013, 'seed': 0, 'steps': 30_000_000,
        'note': 'hand-edited: ünïcode ok', 'nested': {'list': [1, 2.5, None, True]}}


def random_policy(problem, rng, size: int = 20) -> ExemplarPolicy:
    """A random policy whose states use the full precision of a float64."""
    states = rng.uniform(problem.low, problem.high, (size, problem.dim))
    return ExemplarPolicy(problem, states, rng.integers(0, len(problem.actions), size),
                          meta=dict(META))


@pytest.fixture
def acrobot_json(acrobot_problem, rng) -> str:
    """The JSON text of a valid three-exemplar acrobot policy."""
    return random_policy(acrobot_problem, rng, 3).to_json()


def edited(text: str, edit: Callable[[dict], object]) -> str:
    """``text`` parsed, changed in place by ``edit``, and written back as JSON."""
    doc = json.loads(text)
    edit(doc)
    return json.dumps(doc)


def assert_refused(data, expected: str, problem=None) -> PolicyFileError:
    """``data`` is refused with a single-line, short message containing ``expected``."""
    with pytest.raises(PolicyFileError) as info:
        policy_from_json(data, problem)
    message = str(info.value)
    assert expected in message
    assert '\n' not in message and '\r' not in message
    return info.value


# --- round trips --------------------------------------------------------------------------

@pytest.mark.parametrize('name', ['acrobot', 'pdip', 'pdip_single'])
def test_round_trip_is_exact(name, rng):
    """to_json then policy_from_json gives back the same states bit for bit, the same
    actions, problem, style and meta."""
    problem = load_problem(name)
    policy = random_policy(problem, rng, 50)
    back = policy_from_json(policy.to_json(), name)
    assert back.problem == problem and back.style == policy.style
    assert np.array_equal(back.states, policy.states)
    assert np.array_equal(back.actions, policy.actions)
    assert back.meta == META


def test_save_and_load_policy_round_trip(acrobot_problem, rng, tmp_path):
    """save then load_policy gives back the same policy, and save never leaves temporary
    files behind."""
    policy = random_policy(acrobot_problem, rng)
    path = policy.save(tmp_path / 'sub' / 'p.json')
    back = load_policy(path, 'acrobot')
    assert np.array_equal(back.states, policy.states)
    assert np.array_equal(back.actions, policy.actions)
    assert [p.name for p in path.parent.iterdir()] == ['p.json']


def test_document_has_the_spec_fields_one_exemplar_per_line(acrobot_problem, rng):
    """The file is the SPEC 3.3 document (format, problem, style, state_names, actions,
    exemplars, meta) with each exemplar on a line of its own, so diffs stay readable."""
    policy = random_policy(acrobot_problem, rng, 7)
    text = policy.to_json()
    doc = json.loads(text)
    assert set(doc) == {'format', 'problem', 'style', 'state_names', 'actions', 'exemplars',
                        'meta'}
    assert doc['format'] == FORMAT and doc['problem'] == 'acrobot'
    assert doc['state_names'] == ['theta1', 'theta2', 'theta1_dot', 'theta2_dot']
    assert doc['actions'] == [-2.0, 0.0, 2.0]
    lines = [ln for ln in text.splitlines() if ln.strip().startswith('{"state"')]
    assert len(lines) == 7
    assert [json.loads(ln.rstrip(','))['action'] for ln in lines] == list(
        policy.action_values)


def test_angles_are_wrapped_on_loading(acrobot_problem, acrobot_json):
    """A hand-edited angle outside [0, 2pi) is accepted and wrapped; velocities are kept."""
    text = edited(acrobot_json, lambda d: d['exemplars'][0].update(
        state=[-0.5, 7.0, -3.0, 20.0]))
    state = policy_from_json(text).states[0]
    assert state[:2] == pytest.approx([2 * np.pi - 0.5, 7.0 - 2 * np.pi])
    assert list(state[2:]) == [-3.0, 20.0]


# --- refused documents --------------------------------------------------------------------

HOSTILE_EDITS = {
    'state of wrong length': (lambda d: d['exemplars'][0].update(state=[1.0, 2.0, 3.0]),
                              'exemplars[0].state'),
    'state not a list': (lambda d: d['exemplars'][1].update(state=4.0), 'exemplars[1].state'),
    'boolean in a state': (lambda d: d['exemplars'][0]['state'].__setitem__(0, True),
                           'exemplars[0].state[0]'),
    'string in a state': (lambda d: d['exemplars'][2]['state'].__setitem__(3, '1.0'),
                          'exemplars[2].state[3]'),
    'null in a state': (lambda d: d['exemplars'][0]['state'].__setitem__(1, None),
                        'exemplars[0].state[1]'),
    'overflowing number': (lambda d: d['exemplars'][0]['state'].__setitem__(2, 'X1e400X'),
                           'exemplars[0].state[2]'),
    'unknown action': (lambda d: d['exemplars'][1].update(action=1.5),
                       'exemplars[1].action'),
    'boolean action': (lambda d: d['exemplars'][0].update(action=False),
                       'exemplars[0].action'),
    'action as a string': (lambda d: d['exemplars'][0].update(action='2.0'),
                           'exemplars[0].action'),
    'exemplar without action': (lambda d: d['exemplars'][2].pop('action'), 'exemplars[2]'),
    'exemplar not an object': (lambda d: d['exemplars'].__setitem__(1, [0, 0, 0, 0]),
                               'exemplars[1]'),
    'empty exemplars': (lambda d: d.update(exemplars=[]), 'exemplars'),
    'exemplars not a list': (lambda d: d.update(exemplars={}), 'exemplars'),
    'state_names mismatch': (lambda d: d.update(state_names=['q1', 'q2', 'w1', 'w2']),
                             'state_names'),
    'state_names reordered': (lambda d: d['state_names'].reverse(), 'state_names'),
    'actions mismatch': (lambda d: d.update(actions=[-1.0, 0.0, 1.0]), 'actions'),
    'actions not numbers': (lambda d: d.update(actions=['left', 'none', 'right']),
                            'actions[0]'),
    'unknown problem': (lambda d: d.update(problem='cartpole'), 'problem'),
    'problem not a string': (lambda d: d.update(problem=['acrobot']), 'problem'),
    'wrong format': (lambda d: d.update(format='sapga-policy/2'), 'format'),
    'missing format': (lambda d: d.pop('format'), 'format'),
    'missing actions': (lambda d: d.pop('actions'), 'actions'),
    'unknown style': (lambda d: d.update(style='via-point-ish'), 'style'),
    'meta not an object': (lambda d: d.update(meta=[1, 2]), 'meta'),
}


@pytest.mark.parametrize('case', list(HOSTILE_EDITS))
def test_inconsistent_documents_are_refused_naming_the_field(case, acrobot_json):
    """Each inconsistency with the problem's configuration is refused with a one-line
    PolicyFileError naming the offending field."""
    edit, field = HOSTILE_EDITS[case]
    text = edited(acrobot_json, edit).replace('"X1e400X"', '1e400')
    assert_refused(text, field)


def test_policy_of_another_problem_is_refused(acrobot_json):
    """An acrobot policy loaded as a pdip policy is refused, naming both problems."""
    error = assert_refused(acrobot_json, 'problem', problem='pdip')
    assert 'acrobot' in str(error) and 'pdip' in str(error)


def test_unknown_problem_lists_the_known_ones(acrobot_json):
    """A policy for an unknown problem is refused, listing the configured problems."""
    error = assert_refused(edited(acrobot_json, lambda d: d.update(problem='cartpole')),
                           'cartpole')
    assert all(name in str(error) for name in ('acrobot', 'pdip', 'pdip_single'))


@pytest.mark.parametrize('literal', ['NaN', 'Infinity', '-Infinity'])
def test_non_finite_literals_are_refused_naming_the_field(literal, acrobot_json):
    """A NaN or Infinity literal in a state (JSON extensions Python would accept) is
    refused, and the message names the field that holds it."""
    doc = json.loads(acrobot_json)
    doc['exemplars'][1]['state'][2] = 'XX'
    text = json.dumps(doc).replace('"XX"', literal)
    error = assert_refused(text, literal)
    assert 'exemplars[1].state[2]' in str(error)


def test_non_finite_literal_in_meta_is_refused(acrobot_json):
    """SPEC 3.3: every number is finite, also in the free-form meta."""
    text = edited(acrobot_json, lambda d: d['meta'].update(value='XX'))
    assert_refused(text.replace('"XX"', 'NaN'), 'NaN')


@pytest.mark.parametrize('cut', [0.5, 0.1, 0.99])
def test_truncated_json_is_refused(cut, acrobot_json):
    """A valid file cut short is refused as malformed JSON with the place it breaks."""
    assert_refused(acrobot_json[:int(len(acrobot_json) * cut)], 'malformed JSON')


@pytest.mark.parametrize('text, expected', [
    ('[' * 100_000 + ']' * 100_000, 'nested'),
    ('{"a": ' * 100_000 + '1' + '}' * 100_000, 'nested'),
    ('[1, 2, 3]', 'top level'),
    ('"sapga-policy/1"', 'top level'),
    ('null', 'top level'),
    ('', 'malformed JSON'),
])
def test_non_documents_are_refused(text, expected):
    """Deeply nested JSON, a top-level array or scalar, and empty input are refused."""
    assert_refused(text, expected)


def test_non_utf8_bytes_are_refused(acrobot_json):
    """Bytes that are not UTF-8 (a Latin-1 file) are refused, saying so and where."""
    data = acrobot_json.encode('utf-8').replace(b'"meta"', b'"m\xe9ta"')
    assert_refused(data, 'UTF-8')
    assert_refused(b'\xff\xfe{\x00}\x00', 'UTF-8')


def test_a_100_mb_file_is_refused_by_size_before_reading(tmp_path, monkeypatch):
    """load_policy refuses a 100 MB file from its size alone, without opening it."""
    path = tmp_path / 'huge.json'
    with open(path, 'wb') as f:
        f.truncate(100 * 2 ** 20)  # sparse: no disk, no time

    def no_open(*args, **kwargs):
        raise AssertionError('load_policy opened a file larger than the limit')

    monkeypatch.setattr(policy_module, 'open', no_open, raising=False)
    with pytest.raises(PolicyFileError) as info:
        load_policy(path)
    message = str(info.value)
    assert str(path) in message and 'limit' in message and '\n' not in message


def test_oversized_text_is_refused(acrobot_json):
    """policy_from_json refuses text or bytes above the size limit before parsing."""
    padding = ' ' * (MAX_POLICY_BYTES + 1 - len(acrobot_json))
    assert_refused((acrobot_json + padding).encode(), 'limit')
    assert_refused(acrobot_json + padding, 'limit')


def test_missing_file_is_refused_with_its_path(tmp_path):
    """A policy path that does not exist gives a PolicyFileError naming it."""
    with pytest.raises(PolicyFileError, match='cannot read'):
        load_policy(tmp_path / 'nope.json')


@pytest.mark.parametrize('field', ['format', 'problem', 'style'])
def test_messages_quote_only_a_short_excerpt_of_huge_values(field, acrobot_json):
    """A 100 kB string in a field is refused with a message of at most 500 characters: the
    message names the field and quotes an excerpt, not the whole value."""
    error = assert_refused(edited(acrobot_json, lambda d: d.update({field: 'x' * 100_000})),
                           field)
    assert len(str(error)) <= 500


# --- sapga-qtable/1 -------------------------------------------------------------------------

@pytest.fixture
def qtable_doc(acrobot_problem) -> dict:
    """A parsed sapga-qtable/1 document of the acrobot with two visited cells."""
    cells = acrobot_problem.ql_tiles_per_dim ** len(acrobot_problem.ql_state_indices)
    q = np.zeros((cells, 3))
    visited = np.zeros(cells, dtype=bool)
    q[[5, 777]] = [[-1.0, -2.5, -3.0], [-0.1, -0.2, -0.3]]
    visited[[5, 777]] = True
    table = QTable(acrobot_problem, q, visited, {'seed': 1})
    return parse_json(table.to_json().encode(), 'q.json')


def test_qtable_round_trip_is_exact(qtable_doc):
    """A Q-table document loads back with exactly the visited cells and values."""
    table = qtable_from_document(qtable_doc, 'q.json')
    assert list(np.flatnonzero(table.visited)) == [5, 777]
    assert table.q[5].tolist() == [-1.0, -2.5, -3.0] and table.q[777].tolist() == [-0.1, -0.2,
                                                                                   -0.3]
    assert np.count_nonzero(table.q) == 6


QTABLE_EDITS = {
    'actions not a list': (lambda d: d.update(actions=5), 'actions'),
    'superscript digit cell': (lambda d: d['q'].update({'\u00b2': [0.0, 0.0, 0.0]}), 'q'),
    'boolean q value': (lambda d: d['q'].update({'5': [0.0, True, 0.0]}), 'q[5]'),
    'unknown problem': (lambda d: d.update(problem='cartpole'), 'problem'),
}


@pytest.mark.parametrize('case', list(QTABLE_EDITS))
def test_hostile_qtable_documents_are_refused(qtable_doc, case):
    """Malformed Q-table documents are refused with a PolicyFileError naming the field,
    never another exception ('\u00b2'.isdigit() is True, but it is no cell number)."""
    edit, field = QTABLE_EDITS[case]
    edit(qtable_doc)
    with pytest.raises(PolicyFileError, match=field.replace('[', r'\[')):
        qtable_from_document(qtable_doc, 'q.json')


def test_qtable_parser_refuses_non_finite_literals(qtable_doc):
    """A Q-table file with a NaN literal is refused, naming the cell, as a policy file is."""
    text = json.dumps(qtable_doc).replace('-2.5', 'NaN')
    with pytest.raises(PolicyFileError, match=r'q\[.*NaN'):
        qtable_from_document(parse_json(text.encode(), 'q.json'), 'q.json')
