"""Killed runs lose little (sapga train, sapga_ros/cli/train.py; issue 7): the best policy,
the log and the checkpoint are saved every ``--checkpoint-seconds`` by default, a SIGKILL
leaves a policy ``sapga eval`` accepts, and ``--resume`` continues to exactly the result of
an uninterrupted run; SIGTERM finishes the round and saves, as Ctrl-C does."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sim_nodes.jit import COMPILING

SAPGA = [sys.executable, '-m', 'sapga_ros.cli.main']
# a small PDIP population: generations of ~20 k steps, so a save comes within a second
SMALL = ['--problem', 'pdip', '--seed', '3', '--pop', '20', '--children', '4', '--l-min', '10',
         '--l-max', '30', '--jobs', '1', '--quiet']


def sapga(*args: object, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([*SAPGA, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ})


def wait_for(paths: list[Path], proc: subprocess.Popen, timeout: float) -> float | None:
    """Seconds until every path exists; None if the run ended successfully first."""
    start = time.monotonic()
    while not all(p.exists() for p in paths):
        if proc.poll() == 0:
            return None
        assert proc.poll() is None, f'the run failed before its first save: {proc.stderr.read()}'
        assert time.monotonic() - start < timeout, f'no save within {timeout} s'
        time.sleep(0.05)
    return time.monotonic() - start


def policy_doc(path: Path) -> dict:
    """The policy document without its wall-clock time stamp."""
    doc = json.loads(path.read_text())
    doc['meta'].pop('time')
    return doc


def log_rows(path: Path) -> list[dict]:
    """The log rows without the (timing-dependent) speed column."""
    with open(path, newline='') as f:
        return [{k: v for k, v in row.items() if k != 'steps_per_s'} for row in csv.DictReader(f)]


def kill_and_resume(tmp_path: Path, budget: int, extra: list[str], after: float | None
                    ) -> dict:
    """Train SIGKILLed after its first save (or after ``after`` seconds) and resumed, and
    again uninterrupted; check the killed run's files and the resumed result; timings.

    A machine fast enough to finish the budget before the kill lands is no failure: the
    budget is multiplied by 4 and both runs are done again, so the kill falls inside the run
    on any machine."""
    for _ in range(4):
        timings = killed_run(tmp_path / f'budget{budget}', budget, extra, after)
        if timings is not None:
            return timings
        budget *= 4
    raise AssertionError(f'every run up to {budget // 4:,d} steps ended before it was killed')


def killed_run(tmp_path: Path, budget: int, extra: list[str], after: float | None
               ) -> dict | None:
    """``kill_and_resume`` at one budget; None if the run ended before the kill."""
    tmp_path.mkdir()
    killed = tmp_path / 'killed.json'
    t0 = time.monotonic()
    proc = subprocess.Popen([*SAPGA, 'train', *extra, '--steps', str(budget), '--out',
                             str(killed)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        saves = [killed, killed.with_suffix('.log.csv'),
                 killed.with_suffix('.ckpt') / 'checkpoint.npz']
        timings = {'first_save_s': wait_for(saves, proc, timeout=120)}
        if after is not None:
            time.sleep(max(0.0, after - (time.monotonic() - t0)))
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    doc = json.loads(killed.read_text()) if killed.exists() else None
    if proc.returncode == 0 or doc['meta']['steps'] >= budget:
        return None                         # the whole budget ran before the kill
    timings['killed_after_s'] = time.monotonic() - t0
    assert proc.returncode == -signal.SIGKILL
    ev = sapga('eval', killed, '--json')
    assert ev.returncode == 0, ev.stderr
    assert json.loads(ev.stdout)['return'] == doc['meta']['value']

    t0 = time.monotonic()
    full = tmp_path / 'full.json'
    done = sapga('train', *extra, '--steps', budget, '--out', full)
    assert done.returncode == 0, done.stderr
    timings['uninterrupted_s'] = time.monotonic() - t0

    t0 = time.monotonic()
    resumed = sapga('train', '--resume', '--out', killed, '--quiet')   # settings: the ckpt's
    timings['resumed_s'] = time.monotonic() - t0
    assert resumed.returncode == 0, resumed.stderr
    assert policy_doc(killed) == policy_doc(full)
    assert log_rows(killed.with_suffix('.log.csv')) == log_rows(full.with_suffix('.log.csv'))
    return timings


def test_a_killed_run_leaves_an_evaluable_policy_and_resumes_to_the_uninterrupted_result(
        tmp_path):
    """SIGKILL after the first save (1 s period) leaves a policy whose `sapga eval` return is
    its meta value, and `--resume` alone finishes with the uninterrupted run's policy and
    log rows."""
    timings = kill_and_resume(tmp_path, 3_000_000, [*SMALL, '--checkpoint-seconds', '1'],
                              after=None)
    print(timings)


def test_a_killed_cmaes_run_resumes_to_the_uninterrupted_result(tmp_path):
    """`sapga train --method cmaes --problem acrobot --seed 0` SIGKILLed after its first save
    leaves an evaluable policy, and `--resume` (pycma's state re-derived from the checkpoint)
    finishes with the uninterrupted run's policy and log rows."""
    timings = kill_and_resume(tmp_path, 400_000, [
        '--method', 'cmaes', '--problem', 'acrobot', '--seed', '0', '--jobs', '1', '--quiet',
        '--checkpoint-seconds', '1'], after=None)
    print(timings)


@pytest.mark.long
def test_kill_9_of_a_60_million_step_pdip_run_after_40_s_loses_nothing_on_resume(tmp_path):
    """Issue 7's acceptance: `sapga train --problem pdip --steps 60000000` killed after 40 s
    (default save period) leaves a policy `sapga eval` accepts and a checkpoint that
    `--resume` continues to the uninterrupted run's result."""
    timings = kill_and_resume(tmp_path, 60_000_000, ['--problem', 'pdip', '--quiet'],
                              after=40.0)
    print(timings)
    assert timings['killed_after_s'] >= 40.0


def test_sigterm_finishes_the_round_saves_and_exits_143(tmp_path):
    """SIGTERM during `sapga train` ends the run after its round with the best policy, log
    and checkpoint written, exit status 143; the checkpoint resumes."""
    out = tmp_path / 'p.json'
    proc = subprocess.Popen([*SAPGA, 'train', *SMALL[:-1], '--steps', '100000000', '--out',
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        first = proc.stderr.readline()        # the first progress line: training is under way
        if first.rstrip('\n') == COMPILING:     # (after compiling, on a cold numba cache)
            first = proc.stderr.readline()
        assert first.startswith('steps'), first + proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 143, stderr
    assert 'SIGTERM' in stderr and 'Traceback' not in stderr
    meta = json.loads(out.read_text())['meta']
    assert 0 < meta['steps'] < 100_000_000
    assert out.with_suffix('.log.csv').is_file()
    assert (out.with_suffix('.ckpt') / 'checkpoint.npz').is_file()
    resumed = sapga('train', '--resume', '--out', out, '--steps', meta['steps'] + 1, '--quiet')
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(out.read_text())['meta']['steps'] > meta['steps']
