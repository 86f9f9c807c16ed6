"""Running the ``sapga`` command: in a fresh process reading its peak memory, or in this
process (fast) with its output captured."""
from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from pathlib import Path

import pytest


def sapga_peak_rss(argv: list[str]) -> tuple[int, str, int]:
    """(exit status, stderr, peak RSS [MiB]) of ``sapga ARGV`` in a fresh process.

    The peak is VmHWM of /proc/self/status: that of the process's own memory since exec
    (getrusage's ru_maxrss would count the forking test process too)."""
    code = ('import re, sys\nfrom sapga_ros.cli import main\n'
            f'rc = main.main({argv!r})\n'
            'status = open("/proc/self/status").read()\n'
            'print(int(re.search(r"VmHWM:\\s+(\\d+) kB", status).group(1)) // 1024)\n'
            'sys.exit(rc)')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120)
    return done.returncode, done.stderr, int(done.stdout.split()[-1])


def sapga_in_process(argv: list[str], env: dict[str, str] | None = None,
                     cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``sapga ARGV`` run by calling the command's ``main`` in this process, its exit
    status, stdout and stderr captured as a finished subprocess's: the same code path as
    the executable without the ~2 s start-up of a fresh Python.  An exception that escapes
    ``main`` (a traceback, from the executable) fails the calling test.  ``env``: variables
    set for the call (cached problems are dropped around it); ``cwd``: the working directory
    for the call.  Tests that need a fresh process (peak memory, signals, Ray) use
    subprocess; each command keeps at least one such test."""
    from sapga_ros.cli import main as cli
    from sim_nodes.problem import load_problem

    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as patch:
        for key, value in (env or {}).items():
            patch.setenv(key, value)
        if cwd is not None:
            patch.chdir(cwd)
        if env:
            load_problem.cache_clear()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    code = cli.main([str(a) for a in argv])
                except SystemExit as exc:          # argparse's usage errors
                    code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
        finally:
            if env:
                load_problem.cache_clear()
    return subprocess.CompletedProcess(['sapga', *map(str, argv)], code, out.getvalue(),
                                       err.getvalue())
