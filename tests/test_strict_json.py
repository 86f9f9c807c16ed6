"""Every JSON the package writes is strict (no bare NaN or Infinity) and every reader refuses
a bare one with one line naming the file and the field: checkpoints keep an inf or NaN of
the run tagged and read it back as the same float (sapga_ros/io/jsonfile.py,
io/checkpoint.py), and still read the bare constants earlier versions wrote; data files
write null."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sapga_ros.errors import DataFileError
from sapga_ros.io.checkpoint import FILENAME, load_checkpoint, save_checkpoint
from sapga_ros.io.jsonfile import read_json, write_json
from sapga_ros.optim.cmaes import Cmaes, CmaesParams
from sapga_ros.optim.qlearner import QLearning, QlParams
from sapga_ros.optim.sapga import SapGA, SapgaParams
from sapga_ros.training import checkpoints
from sapga_ros.training.loop import TrainConfig, train
from sim_nodes.problem import load_problem

SMALL = SapgaParams(n_pop=10, n_child=2, l_min=5, l_max=10)
RUN = dict(problem='acrobot', delta=0.05, seed=3, jobs=1, params=SMALL)
CLI_RUN = ['--problem', 'acrobot', '--delta', '0.05', '--seed', '3', '--jobs', '1', '--pop',
           '10', '--children', '2', '--l-min', '5', '--l-max', '10', '--quiet']


def _refuse(name: str) -> float:
    raise AssertionError(f'bare {name} written')


def strict(raw: bytes) -> dict:
    """``json.loads`` that fails on a bare NaN or Infinity."""
    return json.loads(raw, parse_constant=_refuse)


def same(a: object, b: object) -> bool:
    """Equal, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def fresh(method: str):
    """A new optimizer of ``method``: no episode has reached anything (best value -inf,
    delta* inf)."""
    problem = load_problem('acrobot')
    if method == 'sapga':
        return SapGA.create(problem, SMALL, 3), SapGA
    if method == 'cmaes':
        return Cmaes.create(problem, CmaesParams(), 3), Cmaes
    return QLearning.create(problem, QlParams(), 3, 0.05, 10_000), QLearning


@pytest.mark.parametrize('method', ['sapga', 'cmaes', 'ql'])
def test_a_checkpoint_of_non_finite_counters_round_trips(method, tmp_path):
    """The checkpoint of a run before any episode reached anything is strict JSON and
    restores the same inf counters."""
    opt, cls = fresh(method)
    before = opt.counters()
    assert any(isinstance(v, float) and not math.isfinite(v) for v in before.values())
    run = {'problem': 'acrobot', 'method': method}
    history = [{'steps': 0, 'delta_star': math.inf, 'best_value': -math.inf, 'x': math.nan}]
    checkpoints.save(str(tmp_path), run, {'budget': 1}, opt, history)
    with np.load(tmp_path / FILENAME) as data:
        strict(data['meta'].tobytes())
    problem = load_problem('acrobot')
    params = {'sapga': SMALL, 'cmaes': CmaesParams(), 'ql': QlParams()}[method]
    again, log = checkpoints.restore(str(tmp_path), run, lambda state: cls.from_state(
        problem, params, state, delta=0.05, budget=10_000))
    after = again.counters()
    assert after.keys() == before.keys()
    assert all(same(before[k], after[k]) for k in before), (before, after)
    assert log[0]['delta_star'] == math.inf and log[0]['best_value'] == -math.inf
    assert math.isnan(log[0]['x'])


def test_a_tagged_lookalike_stays_a_mapping(tmp_path):
    """Only the exact tag reads as a float: other one-key objects are left alone."""
    save_checkpoint(tmp_path, {'a': {'$nonfinite': 'big'}, 'b': [math.inf]}, {})
    meta, _ = load_checkpoint(tmp_path)
    assert meta['a'] == {'$nonfinite': 'big'} and meta['b'] == [math.inf]


def test_a_checkpoint_of_an_earlier_version_with_bare_constants_resumes(tmp_path):
    """Earlier versions wrote a checkpoint's inf counters as bare Infinity: such a file,
    our own tool's, still resumes (every field is checked after parsing) to the
    uninterrupted result."""
    ck = tmp_path / 'ck'
    train(TrainConfig(**RUN, steps=30_000, checkpoint=str(ck)))
    with np.load(ck / FILENAME) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.pop('meta')
    meta, _ = load_checkpoint(ck)                    # tagged non-finite floats as floats
    meta['legacy_check'] = [math.inf, -math.inf]
    raw = json.dumps(meta).encode()                   # the old writer: allow_nan=True
    assert b'Infinity' in raw
    np.savez(ck / FILENAME, **arrays, meta=np.frombuffer(raw, np.uint8))
    assert load_checkpoint(ck)[0]['legacy_check'] == [math.inf, -math.inf]
    resumed = train(TrainConfig(**RUN, steps=60_000, checkpoint=str(ck), resume=True))
    whole = train(TrainConfig(**RUN, steps=60_000))
    assert np.array_equal(resumed.policy.states, whole.policy.states)
    assert np.array_equal(resumed.policy.actions, whole.policy.actions)


def test_data_files_write_null_and_refuse_a_bare_constant_by_field(tmp_path):
    """``write_json`` writes a non-finite number as null; ``read_json`` of a hand-made file
    with a bare NaN names the file and the field."""
    path = tmp_path / 'runs.json'
    write_json(path, {'runs': [{'best': math.inf}, {'best': math.nan}]})
    assert strict(path.read_bytes()) == {'runs': [{'best': None}, {'best': None}]}
    path.write_text('{"runs": [{"best": 1.0}, {"best": NaN}]}')
    with pytest.raises(DataFileError) as err:
        read_json(path, 10_000)
    assert str(err.value) == (f'{path}: not valid JSON (field runs[1].best: bare NaN, a '
                              'non-finite number)')


def test_a_key_given_twice_is_refused_by_every_reader(tmp_path):
    """A JSON object with a key twice is refused with one line naming it, by the data-file
    reader and by the policy readers (whole and streamed, top level and nested): a reader
    keeping the first and one keeping the last would read different documents."""
    from sapga_ros.errors import PolicyFileError
    from sapga_ros.policies.exemplar import ExemplarPolicy
    from sapga_ros.policies.jsonfile import parse_json
    from sapga_ros.policies.jsonstream import read_document
    from sapga_ros.policies.runnable import load_policy
    data = tmp_path / 'summary.json'
    data.write_text('{"a": 1, "b": {"c": 2, "c": 3}}')
    with pytest.raises(DataFileError, match="key 'c' given twice"):
        read_json(data, 10_000)
    for text in ('{"delay": 1, "delay": 2}', '{"x": [{"y": 1, "y": 1}]}'):
        with pytest.raises(PolicyFileError, match='given twice'):
            parse_json(text, 'p.json')
        with pytest.raises(PolicyFileError, match='given twice'):
            read_document(text, 'p.json', frozenset({'x'})).complete()
    problem = load_problem('acrobot')
    good = tmp_path / 'p.json'
    ExemplarPolicy(problem, problem.initial_state[None, :], [2]).save(good)
    doc = good.read_text().rstrip()
    assert doc.endswith('}')
    bad = tmp_path / 'twice.json'
    bad.write_text(doc[:-1] + ', "problem": "pdip"}')
    with pytest.raises(PolicyFileError, match=r'twice\.json: problem: given twice'):
        load_policy(bad)
    assert len(load_policy(good)) == 1


def test_a_q_table_cell_given_twice_is_refused(tmp_path):
    """A Q-table's cell given twice, as the same key or as two spellings of one number, is
    refused by the streamed reader, one line naming it."""
    from sapga_ros.errors import PolicyFileError
    from sapga_ros.policies.kinds import load_any_policy
    q = tmp_path / 'q.json'
    train(TrainConfig(problem='pendulum', method='ql', steps=20_000, jobs=1,
                      ql=QlParams(chunk_steps=10_000))).policy.save(q)
    doc = q.read_text()
    cell = next(iter(json.loads(doc)['q']))
    at = doc.index(f'"{cell}":')
    for twin, words in ((cell, f"key '{cell}' given twice"),
                        ('0' + cell, f'cell {int(cell)} given twice')):
        bad = tmp_path / f'twice-{len(twin)}.json'
        bad.write_text(doc[:at] + f'"{twin}": {json.dumps(json.loads(doc)["q"][cell])}, '
                       + doc[at:])
        with pytest.raises(PolicyFileError, match=words):
            load_any_policy(bad)
    assert load_any_policy(q) is not None
