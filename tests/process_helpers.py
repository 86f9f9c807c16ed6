"""Running the ``sapga`` command in a fresh process and reading its peak memory."""
from __future__ import annotations

import subprocess
import sys


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
