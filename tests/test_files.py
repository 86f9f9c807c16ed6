"""Every file the package reads is opened as a regular file with bounded size (a FIFO, a
device or a directory given as a file is refused at once, never waited on), and atomic
writes never touch the process umask."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from sapga_ros.errors import SapgaError
from sapga_ros.policies.kinds import load_any_policy
from sapga_ros.policies.runnable import load_policy
from sapga_ros.io.atomic import process_umask, write_atomic
from sim_nodes.errors import ConfigError
from sim_nodes.problem import load_problem_file


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / 'pipe'
    os.mkfifo(path)
    return path


@pytest.mark.parametrize('reader', [load_policy, load_any_policy, load_problem_file])
def test_a_fifo_or_device_is_refused_without_waiting_for_a_writer(fifo, reader):
    """No writer ever opens the FIFO: the reader must not block on it."""
    for path in (fifo, '/dev/zero', fifo.parent):
        with pytest.raises((SapgaError, ConfigError), match='not a regular file'):
            reader(path)


def test_sapga_eval_of_a_fifo_is_one_line_exit_2(fifo):
    """The CLI path: one line naming the file, status 2, no traceback, no hang."""
    done = subprocess.run([sys.executable, '-m', 'sapga_ros.cli.main', 'eval', str(fifo)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and 'a FIFO, not a regular file' in lines[0]


def test_an_oversized_problem_file_is_refused_before_reading(tmp_path):
    """The size is checked on the open file before a byte is read."""
    big = tmp_path / 'big.yaml'
    with open(big, 'wb') as f:
        f.truncate(50 << 20)
    with pytest.raises(ConfigError, match='larger than'):
        load_problem_file(big)


def test_atomic_writes_leave_the_umask_alone_under_threads(tmp_path):
    """While files are written atomically, another thread reads the umask it set, always."""
    old = os.umask(0o027)
    try:
        seen = set()
        stop = threading.Event()

        def watch():
            while not stop.is_set():
                seen.add(process_umask())
        watcher = threading.Thread(target=watch)
        watcher.start()
        for k in range(300):
            write_atomic(tmp_path / f'f{k}.txt', 'x')
        stop.set()
        watcher.join()
        assert seen == {0o027}
        assert (tmp_path / 'f0.txt').stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(old)
