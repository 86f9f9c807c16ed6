"""Policy files are read in memory a small multiple of their size (sapga_ros/policies/
jsonstream.py): hostile documents that ``json.loads`` would blow up ~24-fold are refused with
one line and exit status 2 while the process's peak RSS stays near that of a tiny policy;
fields in any order, bounds on a field, an item and the item count."""
from __future__ import annotations

import json

import numpy as np
import pytest

import sapga_ros.policies.jsonstream as jsonstream
from process_helpers import sapga_peak_rss
from sapga_ros.errors import PolicyFileError
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import policy_from_json
from sapga_ros.policies.kinds import any_policy_from_json
from sapga_ros.policies.qtable import QTable
from sim_nodes.problem import load_problem

SIZE = 48 * 2 ** 20        # [bytes] of each hostile file: json.loads would take ~1.1 GB


def one_exemplar_doc() -> dict:
    pr = load_problem('acrobot')
    return json.loads(ExemplarPolicy(pr, pr.initial_state[None, :], [0]).to_json())


def hostile(kind: str) -> str:
    """A document of about SIZE bytes, made of what costs Python most per byte."""
    head = json.dumps(one_exemplar_doc())
    n = SIZE // 3
    if kind == 'meta of empty lists':
        return head.replace('"meta": {}', '"meta": {"x": [' + '[],' * n + '[]]}')
    if kind == 'exemplars of empty objects':
        return head.replace('"exemplars": [', '"exemplars": [' + '{},' * n)
    if kind == 'one exemplar of nested lists':
        return head.replace('"exemplars": [', '"exemplars": [{"state": [' + '[],' * n
                            + '[]], "action": 0.0}, ')
    if kind == 'q-table rows of empty lists':
        pr = load_problem('acrobot')
        table = QTable(pr, np.zeros((1, 3)), np.zeros(1, bool), {})
        return table.to_json().replace('"q": {', '"q": {' + '"0":[],' * (n // 2))
    raise ValueError(kind)


@pytest.fixture(scope='module')
def base_mib(tmp_path_factory) -> int:
    """Peak RSS [MiB] of `sapga eval` of a one-exemplar policy: the process's own need."""
    path = tmp_path_factory.mktemp('tiny') / 'tiny.json'
    path.write_text(json.dumps(one_exemplar_doc()))
    rc, stderr, peak = sapga_peak_rss(['eval', str(path)])
    assert rc == 0, stderr
    return peak


@pytest.mark.parametrize('kind, needle', [
    ('meta of empty lists', 'meta: longer than 1048576 characters'),
    ('exemplars of empty objects', 'exemplars[0]: expected an object with'),
    ('one exemplar of nested lists', 'exemplars[0]: longer than 65536 characters'),
    ('q-table rows of empty lists', 'q[0]: expected 3 numbers'),
])
def test_hostile_files_are_refused_in_bounded_memory(kind, needle, base_mib, tmp_path):
    """`sapga eval` of a 48 MB hostile file exits 2 with one line naming the field, its peak
    RSS at most 2 times the file's size above a tiny policy's (json.loads of the whole
    file took about 24 times: 1.8 GB for 62 MB)."""
    path = tmp_path / 'hostile.json'
    path.write_text(hostile(kind))
    size_mib = path.stat().st_size / 2 ** 20
    rc, stderr, peak = sapga_peak_rss(['eval', str(path)])
    assert rc == 2 and stderr.count('\n') == 1 and needle in stderr, stderr
    assert 'Traceback' not in stderr
    assert peak - base_mib <= 2 * size_mib, (peak, base_mib, size_mib)


def test_a_file_over_the_size_bound_is_refused_in_one_line(tmp_path):
    """A 65 MB policy file is refused from its size, exit status 2, one line stating the
    64 MB bound."""
    path = tmp_path / 'huge.json'
    with open(path, 'wb') as f:
        f.truncate(65 * 2 ** 20)
    rc, stderr, peak = sapga_peak_rss(['eval', str(path)])
    assert rc == 2 and stderr.count('\n') == 1, stderr
    assert f'{path}: larger than the 64 MB limit' in stderr


def test_fields_in_any_order_are_read(acrobot_problem):
    """Exemplars before the header and meta after them (a hand-edited file) read as the
    package's own order does."""
    pr = acrobot_problem
    rng = np.random.default_rng(1)
    policy = ExemplarPolicy(pr, rng.uniform(pr.low, pr.high, (9, 4)), rng.integers(0, 3, 9),
                            meta={'note': 'x'})
    doc = json.loads(policy.to_json())
    reordered = {'exemplars': doc['exemplars'], 'meta': doc['meta'],
                 **{k: v for k, v in doc.items() if k not in ('exemplars', 'meta')}}
    for text in (policy.to_json(), json.dumps(reordered)):
        for read in (policy_from_json, any_policy_from_json):
            back = read(text)
            assert np.array_equal(back.states, policy.states) and back.meta == {'note': 'x'}
            assert np.array_equal(back.actions, policy.actions)


@pytest.mark.parametrize('edit, needle', [
    (lambda t: t[:-3], 'malformed JSON'),
    (lambda t: t + '[]', 'Extra data'),
    (lambda t: t.replace('"exemplars": [', '"exemplars": [ , '), 'malformed JSON'),
    (lambda t: t.replace('}\n ]', '}}\n ]'), 'malformed JSON'),
    (lambda t: t.replace('"meta": {', '"exemplars": [{"state": [0, 0, 0, 0], "action": 0.0}], '
                         '"meta": {'), 'exemplars: given twice'),
    (lambda t: t.replace('"meta": {', '"meta": {"x": "' + 'y' * 2 ** 21 + '", '),
     'meta: longer than'),
])
def test_syntax_and_bounds_are_checked_to_the_end(edit, needle, acrobot_problem):
    """A broken document is refused however far into it the break is, with one line; a
    field over its bound is refused naming it."""
    pr = acrobot_problem
    text = ExemplarPolicy(pr, np.tile(pr.initial_state, (3, 1)), [0, 1, 2]).to_json()
    for read in (policy_from_json, any_policy_from_json):
        with pytest.raises(PolicyFileError, match=needle.replace('[', r'\[')) as info:
            read(edit(text))
        assert '\n' not in str(info.value)


def test_more_items_than_the_bound_are_refused(monkeypatch, acrobot_problem):
    """A bulk field of more items than MAX_ITEMS is refused, naming it."""
    monkeypatch.setattr(jsonstream, 'MAX_ITEMS', 5)
    pr = acrobot_problem
    text = ExemplarPolicy(pr, np.tile(pr.initial_state, (8, 1)), [0] * 8).to_json()
    with pytest.raises(PolicyFileError, match='exemplars: more than 5 items'):
        policy_from_json(text)
    five = ExemplarPolicy(pr, np.tile(pr.initial_state, (5, 1)), [0] * 5).to_json()
    assert len(policy_from_json(five)) == 5


def test_exemplars_are_checked_where_they_stand(tmp_path):
    """load_policy reads a file by its path the same way (one exemplar's error names it)."""
    doc = one_exemplar_doc()
    doc['exemplars'].append({'state': [0, 0, 0], 'action': 0.0})
    path = tmp_path / 'p.json'
    path.write_text(json.dumps(doc))
    with pytest.raises(PolicyFileError, match=r'p.json: exemplars\[1\].state: expected 4'):
        any_policy_from_json(path.read_bytes(), source=str(path))
