"""Checkpoints as hostile input (sapga_ros/io/checkpoint.py, training/checkpoints.py) and the
files of `sapga train` (cli/train_plan.py): every damaged checkpoint is one line and exit 2,
never a traceback nor a crash after the run; a zip bomb is refused before it inflates; a
resumed run takes its settings from the checkpoint; outputs are checked before training."""
from __future__ import annotations

import io
import json
import os
import re
import stat
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from process_helpers import sapga_peak_rss
from sapga_ros.cli import main as cli
from sapga_ros.errors import CheckpointError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import NotRegularFile
from sapga_ros.io.checkpoint import FILENAME, load_checkpoint
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train

SMALL = SapgaParams(n_pop=10, n_child=2, l_min=5, l_max=10)
RUN = dict(problem='acrobot', delta=0.05, seed=3, jobs=1, params=SMALL)
CLI_RUN = ['--problem', 'acrobot', '--delta', '0.05', '--seed', '3', '--jobs', '1', '--pop',
           '10', '--children', '2', '--l-min', '5', '--l-max', '10', '--quiet']


@pytest.fixture(scope='module')
def good(tmp_path_factory) -> tuple[dict, dict]:
    """(arrays, meta) of the checkpoint of a tiny SAP-GA run."""
    ck = tmp_path_factory.mktemp('good')
    train(TrainConfig(**RUN, steps=30_000, checkpoint=str(ck)))
    with np.load(ck / FILENAME) as data:
        arrays = {k: data[k] for k in data.files}
    return arrays, json.loads(arrays.pop('meta').tobytes())


def write(directory: Path, arrays: dict, meta: dict | bytes) -> Path:
    """A checkpoint of ``arrays`` and ``meta`` (a document, or the record's raw bytes)."""
    directory.mkdir(parents=True, exist_ok=True)
    raw = meta if isinstance(meta, bytes) else json.dumps(meta, allow_nan=True).encode()
    np.savez(directory / FILENAME, **arrays, meta=np.frombuffer(raw, np.uint8))
    return directory


def with_meta(**changes: object) -> Callable:
    """A variant of the good meta with ``stats.x`` / ``x`` keys changed."""
    def change(arrays: dict, meta: dict) -> tuple[dict, dict]:
        meta = json.loads(json.dumps(meta))
        for key, value in changes.items():
            *path, last = key.split('__')
            target = meta
            for part in path:
                target = target[part]
            target[last] = value
        return arrays, meta
    return change


def with_array(name: str, make: Callable[[np.ndarray], np.ndarray]) -> Callable:
    return lambda arrays, meta: ({**arrays, name: make(arrays[name])}, meta)


def deep(arrays: dict, meta: dict) -> tuple[dict, bytes]:
    text = json.dumps(meta)[:-1] + ', "x": ' + '[' * 100_000 + ']' * 100_000 + '}'
    return arrays, text.encode()


VARIANTS = {
    'float pop_lengths': with_array('pop_lengths', lambda a: a.astype(float)),
    'scalar pop_lengths': with_array('pop_lengths', lambda a: np.array(5)),
    '100k-deep meta JSON': deep,
    'string stats.generation': with_meta(stats__generation='5'),
    'string stats.steps': with_meta(stats__steps='5'),
    'infinite stats.steps': with_meta(stats__steps=float('inf')),
    'negative generation': with_meta(stats__generation=-5),
    'fractional generation': with_meta(stats__generation=5.5),
    'boolean generation': with_meta(stats__generation=True),
    'null delta_star': with_meta(stats__delta_star=None),
    'string best_value': with_meta(stats__best_value='x'),
    'short pop_used': with_array('pop_used', lambda a: a[:-3]),
    'history a string': with_meta(history='abc'),
    'history a mapping': with_meta(history={'a': 1}),
    'history of numbers': with_meta(history=[1, 2, 3]),
    'history row of strings': with_meta(history=[{'steps': 'x'}]),
    'generator state out of range': with_meta(rng={'bit_generator': 'PCG64', 'has_uint32': 0,
                                                   'uinteger': 0,
                                                   'state': {'state': -1, 'inc': 2 ** 200}}),
    'generator state a string': with_meta(rng='x'),
    'unknown counter': with_meta(stats__zzz=1),
    '5000-digit number in meta': lambda arrays, meta: (
        arrays, json.dumps(meta)[:-1].encode() + b', "x": ' + b'9' * 5000 + b'}'),
    'meta a list': lambda arrays, meta: (arrays, b'[1, 2]'),
    'run settings a string': with_meta(run='x'),
    'fractional actions': with_array('pop_actions', lambda a: a + 0.5),
    'one-dimensional states': with_array('pop_states', lambda a: a.ravel()),
    'string values': with_array('pop_values', lambda a: np.array(['x'] * len(a))),
    'short pop_has_used': with_array('pop_has_used', lambda a: a[:3]),
    'catch scale out of range': with_array('pop_catch_scale', lambda a: a * 100),
    'short pop_catch_scale': with_array('pop_catch_scale', lambda a: a[:3]),
    'nan catch scale': with_array('pop_catch_scale', lambda a: a * np.nan),
    'two best policies': with_array('best_lengths', lambda a: np.array([3, 3])),
    'huge exemplar counts': with_array('pop_lengths', lambda a: np.full(len(a), 2 ** 62)),
}


@pytest.mark.parametrize('name', list(VARIANTS))
def test_each_damaged_checkpoint_is_one_line_and_exit_2(name, good, tmp_path, capsys):
    """`sapga train --resume` of each crafted checkpoint exits 2 with one line naming the
    checkpoint: nothing is trained, no traceback, no crash after the run."""
    arrays, meta = VARIANTS[name](*good)
    ck = write(tmp_path / 'ck', arrays, meta)
    code = cli.main(['train', *CLI_RUN, '--steps', '60000', '--resume', '--checkpoint', str(ck),
                     '--out', str(tmp_path / 'p.json')])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count('\n') == 1 and err.startswith('sapga train: error: ') and str(ck) in err
    assert not (tmp_path / 'p.json').exists()


@pytest.mark.parametrize('content, needle', [
    (b'', 'not a zip file'), (b'PK\x03\x04broken', 'not a zip file'),
    (b'hello', 'not a zip file')])
def test_files_that_are_no_zip_are_refused(content, needle, tmp_path):
    """Empty, truncated or foreign files are refused as unreadable, naming the file."""
    (tmp_path / FILENAME).write_bytes(content)
    with pytest.raises(CheckpointError, match=re.escape(str(tmp_path / FILENAME))) as err:
        load_checkpoint(tmp_path)
    assert needle in str(err.value).lower()


def test_a_directory_or_fifo_as_checkpoint_is_refused_at_once(tmp_path):
    """A directory or a FIFO named checkpoint.npz is refused without blocking."""
    (tmp_path / 'd' / FILENAME).mkdir(parents=True)
    with pytest.raises(CheckpointError, match='a directory, not a regular file'):
        load_checkpoint(tmp_path / 'd')
    (tmp_path / 'f').mkdir()
    os.mkfifo(tmp_path / 'f' / FILENAME)
    with pytest.raises(CheckpointError, match='a FIFO, not a regular file'):
        load_checkpoint(tmp_path / 'f')


def test_an_array_header_larger_than_its_data_is_refused_unallocated(good, tmp_path):
    """A member whose .npy header claims 10^10 values (75 GiB) is refused, not allocated."""
    arrays, meta = good
    buf = io.BytesIO()
    np.save(buf, arrays['pop_values'])
    raw = buf.getvalue().replace(f'({len(arrays["pop_values"])},)'.encode(),
                                 b'(10000000000,)')
    record = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    with zipfile.ZipFile(tmp_path / FILENAME, 'w') as z:
        for key, value in {**arrays, 'meta': record}.items():
            b = io.BytesIO()
            np.save(b, value)
            z.writestr(f'{key}.npy', raw if key == 'pop_values' else b.getvalue())
    with pytest.raises(CheckpointError, match='does not match its'):
        load_checkpoint(tmp_path)


def zip_bomb(path: Path, size: int = 3_200 * 2 ** 20) -> Path:
    """A 3.2 MB NPZ whose one member, meta.npy, inflates to ``size`` bytes (3.4 GB): a
    deflate stream of one block of zeros repeated (each ends with a full flush, so the
    blocks are byte-identical), with its correct CRC."""
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {'descr': '|u1', 'fortran_order': False,
                                                'shape': (size,)})
    header, block = head.getvalue(), bytes(2 ** 20)
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = c.compress(header) + c.flush(zlib.Z_FULL_FLUSH)
    one = c.compress(block) + c.flush(zlib.Z_FULL_FLUSH)
    n = size // len(block)
    stream = first + one * n + c.flush()
    crc = zlib.crc32(header)
    for _ in range(n):
        crc = zlib.crc32(block, crc)
    total, name = len(header) + n * len(block), b'meta.npy'
    local = struct.pack('<4sHHHHHIIIHH', b'PK\x03\x04', 20, 0, 8, 0, 0, crc, len(stream),
                        total, len(name), 0) + name
    central = struct.pack('<4sHHHHHHIIIHHHHHII', b'PK\x01\x02', 20, 20, 0, 8, 0, 0, crc,
                          len(stream), total, len(name), 0, 0, 0, 0, 0, 0) + name
    end = struct.pack('<4sHHHHIIH', b'PK\x05\x06', 0, 0, 1, 1, len(central),
                      len(local) + len(stream), 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(local + stream + central + end)
    return path


def test_a_zip_bomb_checkpoint_is_refused_before_it_inflates(tmp_path):
    """A 3.2 MB checkpoint whose member claims 3.4 GB is refused at once with one line; the
    resuming process's peak RSS (VmHWM) stays small (it was 6.6 GB before the bound)."""
    bomb = zip_bomb(tmp_path / 'ck' / FILENAME)
    assert 3_000_000 < bomb.stat().st_size < 3_500_000
    rc, stderr, peak_mib = sapga_peak_rss(['train', '--resume', '--checkpoint', str(bomb.parent),
                                           '--out', str(tmp_path / 'p.json')])
    assert rc == 2, stderr
    assert stderr.count('\n') == 1 and 'claim 3355443328 bytes uncompressed' in stderr
    assert peak_mib < 400, peak_mib


def test_resume_takes_the_run_settings_from_the_checkpoint(tmp_path, capsys):
    """`--resume --checkpoint DIR` alone continues the checkpoint's run (problem, seed,
    population, budget), to exactly what that run gives uninterrupted."""
    full = train(TrainConfig(**RUN, steps=60_000))
    ck = tmp_path / 'ck'
    assert cli.main(['train', *CLI_RUN, '--steps', '30000', '--checkpoint', str(ck),
                     '--out', str(tmp_path / 'a.json')]) == 0
    out = tmp_path / 'b.json'
    assert cli.main(['train', '--resume', '--checkpoint', str(ck), '--steps', '60000',
                     '--out', str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc['meta']['value'] == full.policy.meta['value']
    assert doc['meta']['steps'] == full.stats['steps']
    assert doc['exemplars'] == json.loads(full.policy.to_json())['exemplars']
    capsys.readouterr()


def test_resume_with_other_settings_names_the_differences(tmp_path, capsys):
    """Resuming a pdip seed 3 checkpoint as acrobot seed 0 is one line naming both."""
    ck = tmp_path / 'ck'
    train(TrainConfig(problem='pdip', seed=3, steps=20_000, jobs=1, params=SMALL,
                      checkpoint=str(ck)))
    code = cli.main(['train', '--resume', '--checkpoint', str(ck), '--problem', 'acrobot',
                     '--seed', '0', '--out', str(tmp_path / 'p.json')])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1
    assert 'checkpoint is of problem pdip' in err and 'seed 3; this run: problem acrobot' in err
    assert 'seed 0' in err


def test_resume_of_a_q_learning_checkpoint_keeps_its_chunks(tmp_path, capsys):
    """A Q-learning run resumed with no options keeps its method, chunk size and budget."""
    ck = tmp_path / 'ck'
    cfg = dict(problem='pdip_single', method='ql', delta=0.01, ql=QlParams(chunk_steps=5000))
    full = train(TrainConfig(**cfg, steps=20_000))
    train(TrainConfig(**cfg, steps=10_000, checkpoint=str(ck)))
    out = tmp_path / 'q.json'
    assert cli.main(['train', '--resume', '--checkpoint', str(ck), '--steps', '20000',
                     '--out', str(out)]) == 0
    meta = json.loads(out.read_text())['meta']
    assert meta['steps'] == full.stats['steps'] and meta['value'] == full.policy.meta['value']
    assert out.with_suffix('.log.csv').read_text().count('\n') == len(full.history) + 1
    capsys.readouterr()


@pytest.mark.parametrize('args, needle', [
    (['--out', '/nonexistent/dir/x.json'], '/nonexistent/dir does not exist'),
    (['--checkpoint', '/nonexistent/dir/ck'], '/nonexistent/dir does not exist'),
    (['--out', 'FILE/x.json'], 'is not a folder'),
    (['--checkpoint', 'FILE'], 'exists and is not a directory'),
    (['--out', '.'], 'is a directory'),
    (['--out', 'FIFO'], 'not a regular file'),
    (['--resume'], 'no checkpoint to resume from'),
    (['--init', 'missing.json'], 'missing.json'),
    (['--init', 'FILE'], 'FILE'),
    (['--l-min', '30', '--l-max', '20'], 'l_min 30 is larger than l_max 20'),
    (['--method', 'ql', '--init', 'FILE'], 'FILE'),
])
def test_user_errors_of_train_are_one_line_exit_2_and_create_nothing(
        args, needle, tmp_path, capsys, monkeypatch):
    """Every mistaken `sapga train` exits 2 with one line before training and creates no
    folder (only the default runs/ of a default --out would be)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'FILE').write_text('not a folder')
    os.mkfifo(tmp_path / 'FIFO')
    args = [a.replace('FILE', str(tmp_path / 'FILE')).replace('FIFO', str(tmp_path / 'FIFO'))
            for a in args]
    code = cli.main(['train', '--problem', 'acrobot', '--steps', '1000', '--quiet', *args])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and needle in err, err
    assert not Path('/nonexistent').exists()
    assert sorted(p.name for p in tmp_path.iterdir()) in (['FIFO', 'FILE'],
                                                          ['FIFO', 'FILE', 'runs'])


def test_an_atomic_write_never_replaces_a_fifo_or_a_directory(tmp_path):
    """write_atomic refuses a path that is a FIFO or a directory (a device such as /dev/null
    alike) and leaves it as it was."""
    os.mkfifo(tmp_path / 'fifo')
    (tmp_path / 'dir').mkdir()
    for name, kind in [('fifo', 'a FIFO'), ('dir', 'a directory')]:
        with pytest.raises(NotRegularFile, match=f'{kind}, not a regular file'):
            write_atomic(tmp_path / name, 'text')
    assert stat.S_ISFIFO(os.stat(tmp_path / 'fifo').st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['dir', 'fifo']


def test_a_default_run_checkpoints_beside_its_policy(tmp_path, capsys, monkeypatch):
    """With no --out nor --checkpoint, the policy, log and checkpoint go to runs/."""
    monkeypatch.chdir(tmp_path)
    assert cli.main(['train', *CLI_RUN, '--steps', '5000']) == 0
    runs = tmp_path / 'runs'
    assert sorted(p.name for p in runs.iterdir()) == [
        'acrobot-sapga-seed3.ckpt', 'acrobot-sapga-seed3.json', 'acrobot-sapga-seed3.log.csv']
    assert (runs / 'acrobot-sapga-seed3.ckpt' / FILENAME).is_file()
    assert 'checkpoint: runs/acrobot-sapga-seed3.ckpt' in capsys.readouterr().out


def test_inspect_refuses_a_plot_path_it_cannot_write(tmp_path, capsys):
    """`sapga inspect --plot` into a directory or a missing folder exits 2 with one line
    before reading the recording."""
    for plot, needle in [(tmp_path, 'is a directory'),
                         (tmp_path / 'no' / 'p.png', 'does not exist')]:
        code = cli.main(['inspect', str(tmp_path / 'missing.mcap'), '--plot', str(plot)])
        err = capsys.readouterr().err
        assert code == 2 and err.count('\n') == 1 and needle in err, err
