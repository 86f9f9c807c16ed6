"""ROS 2 domain ids for tests, safe across parallel test processes (pytest-xdist workers,
other checkouts' test runs on the same host).

A domain is claimed with an exclusive ``flock`` on a lock file under the temporary
directory, held until released (or the process ends, when the kernel drops the lock), and
only if its first Fast DDS participant ports are free (a process that takes no lock, say an
older checkout's run or a ``sapga bench --ros``, still keeps its domain).  Each xdist worker
starts its search at its own place in the range, so workers seldom even try the same lock.
No rclpy here: conftest.py imports this module.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import random
import socket
import tempfile
import time
from pathlib import Path
from typing import Iterator

DOMAINS = range(1, 201)      # 7400 + 250 * 200 + offsets stays below 65535
LOCK_DIR = Path(tempfile.gettempdir()) / 'sapga_ros-test-domains'
_held: dict[int, int] = {}   # domain -> file descriptor holding its lock


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.bind(('', port))
        except OSError:
            return False
    return True


def _ports_free(domain: int) -> bool:
    base = 7400 + 250 * domain  # RTPS port mapping: PB + DG * domain
    return all(_port_free(base + offset) for offset in (0, 1, 10, 11, 12, 13))


def _worker_index() -> int:
    """0 for gw0 (or no xdist), 1 for gw1, ..."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    digits = worker.removeprefix('gw')
    return int(digits) if digits.isdigit() else 0


def _candidates() -> list[int]:
    """Every domain, in an order of this worker's own: its share of the range first
    (shuffled), then the rest (shuffled)."""
    count = max(1, int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1')))
    index = _worker_index() % count
    rng = random.Random(os.getpid() * 1_000_003 + time.monotonic_ns())
    own = [d for d in DOMAINS if d % count == index]
    rest = [d for d in DOMAINS if d % count != index]
    rng.shuffle(own)
    rng.shuffle(rest)
    return own + rest


def claim_domain() -> int:
    """A ROS domain id nobody else on this host uses, locked until ``release_domain``."""
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    for domain in _candidates():
        if domain in _held:
            continue
        fd = os.open(LOCK_DIR / f'{domain}.lock', os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        if _ports_free(domain):
            _held[domain] = fd
            return domain
        os.close(fd)
    raise RuntimeError('no free ROS domain id found')


def release_domain(domain: int) -> None:
    """Give back a domain from ``claim_domain`` (no-op for one not held)."""
    fd = _held.pop(domain, None)
    if fd is not None:
        os.close(fd)    # closing the only descriptor drops the flock


@contextlib.contextmanager
def ros_domain() -> Iterator[int]:
    """A claimed domain id for the life of the ``with`` block."""
    domain = claim_domain()
    try:
        yield domain
    finally:
        release_domain(domain)
