"""Run the ROS test files N times in a row under busy loops: a suite that passes only on a
quiet machine is flaky, and this is how to find out (`make stress-ros`, default 20 runs
under 2 busy loops, the test jobs of `make test`).

The ROS test files are those that start rclpy nodes, launches or node executables (they
import ``ros_helpers`` or ``rclpy``).  Each run's pytest output is kept in ``--out``; a line
per run says how it ended; the exit status is 1 if any run failed.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent
ROS_IMPORT = re.compile(r'^\s*(from|import)\s+(ros_helpers|rclpy)\b', re.M)


def ros_test_files() -> list[str]:
    """The test files that import ros_helpers or rclpy, sorted."""
    return sorted(str(p) for p in HERE.glob('test_*.py') if ROS_IMPORT.search(p.read_text()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--runs', type=int, default=20)
    ap.add_argument('--busy', type=int, default=2, help='busy loops beside the tests')
    ap.add_argument('--jobs', type=int, default=2, help='pytest-xdist workers')
    ap.add_argument('--out', default='stress-ros', help='folder for each run\'s output')
    ap.add_argument('files', nargs='*', help='test files (default: every ROS test file)')
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    files = args.files or ros_test_files()
    busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(args.busy)]
    failed = 0
    try:
        for run in range(1, args.runs + 1):
            start = time.monotonic()
            log = out / f'run{run}.txt'
            with open(log, 'w') as f:
                rc = subprocess.call([sys.executable, '-m', 'pytest', '-q', '-p',
                                      'no:cacheprovider', '-n', str(args.jobs), '--dist',
                                      'worksteal', *files], stdout=f, stderr=subprocess.STDOUT)
            last = log.read_text().strip().splitlines()[-1:] or ['(no output)']
            failed += rc != 0
            print(f'run {run}/{args.runs}: exit {rc}, {time.monotonic() - start:.0f} s: '
                  f'{last[0]}', flush=True)
    finally:
        for p in busy:
            p.kill()
    print(f'{args.runs - failed} of {args.runs} runs passed ({len(files)} files, '
          f'{args.busy} busy loops, {args.jobs} workers)')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
