"""The process supervisor of the launch scripts (``sapga_ros.launch``).

``Supervisor`` starts nodes as child processes (executables found where ``ros2 run``
looks: ``<prefix>/lib/sapga_ros/<exe>``), prefixes every output line with the child's
name, waits for a condition while watching the children, and stops them cleanly: SIGINT to
each child's process group, SIGTERM after ``stop_timeout``, SIGKILL after as long again.  A
required child that exits by itself ends the launch (``ChildExited`` names it and its exit
code); Ctrl-C or SIGTERM to the launcher ends it too (``Interrupted``).  ``launch_main`` is
the body of every launch script's ``main()``.  This module imports no ``rclpy``.
"""
from __future__ import annotations

import contextlib
import ctypes
import math
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence, TextIO

import yaml

from sapga_ros.errors import SapgaError
from sapga_ros.launch.prefix import ensure_ament_prefix
from sapga_ros.launch.ros_args import split_ros_args

PACKAGE = 'sapga_ros'
STOP_TIMEOUT_S = 10.0   # [s] after SIGINT before SIGTERM, and after SIGTERM before SIGKILL
POLL_S = 0.05           # [s] how often waits look at the children and the condition
_PR_SET_PDEATHSIG = 1   # prctl option: signal this process when its parent dies


class LaunchError(SapgaError):
    """A launch cannot go on (bad arguments, missing executable, a node refused a request)."""


class ChildExited(LaunchError):
    """A required child process ended by itself; the launch stopped the others."""

    def __init__(self, name: str, returncode: int) -> None:
        how = (f'was killed by signal {-returncode}' if returncode < 0
               else f'exited with code {returncode}')
        super().__init__(f'{name} {how}; stopped the other nodes')
        self.name = name
        self.returncode = returncode


class Interrupted(LaunchError):
    """The launcher got SIGINT (Ctrl-C) or SIGTERM; the children were stopped."""

    def __init__(self, signum: int) -> None:
        super().__init__(f'interrupted by {signal.Signals(signum).name}; stopped every node')
        self.signum = signum


def find_executable(name: str, package: str = PACKAGE) -> Path:
    """Where ``ros2 run <package> <name>`` finds ``name``, else the console script beside
    this Python (a plain ``pip install`` without the ament index on the path)."""
    candidates = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
        try:
            candidates.append(Path(get_package_prefix(package)) / 'lib' / package / name)
        except (PackageNotFoundError, ValueError):
            pass
    except ImportError:
        pass
    candidates.append(Path(sys.executable).parent / name)
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    raise LaunchError(f'executable {name!r} of {package} not found (looked in '
                      f'{", ".join(str(c.parent) for c in candidates)}); is {package} '
                      'installed?')


def node_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a child node: ours, unbuffered Python, this install's ament
    prefix in ``AMENT_PREFIX_PATH`` (``prefix.py``)."""
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    ensure_ament_prefix(env)
    if sys.stdout.isatty():
        env.setdefault('RCUTILS_COLORIZED_OUTPUT', '1')
    env.update(extra or {})
    return env


def write_params_file(path: Path, params: dict[str, Any]) -> Path:
    """A ``--params-file`` for any node name (``/**``); values keep their YAML types."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': params}}, sort_keys=False),
                    encoding='utf-8')
    return path


def _parent_death_signal() -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes a child get SIGTERM if the launcher dies (Linux only)."""
    if not sys.platform.startswith('linux'):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)


@dataclass
class Child:
    """One supervised child process."""

    name: str
    argv: list[str]
    proc: subprocess.Popen
    required: bool = True
    reader: threading.Thread | None = field(default=None, repr=False)

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def signal(self, signum: int) -> None:
        """Send ``signum`` to the child's process group (the child and what it started)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signum)
            except ProcessLookupError:
                pass


class Supervisor:
    """Starts, watches and stops child processes; their output lines carry their name.

    Use as a context manager (children are stopped on the way out, whatever happened)::

        with Supervisor() as sup, sup.handle_signals():
            sup.start('sim', [exe, '--ros-args', ...])
            sup.wait(lambda: episode_done(), what='the episode')
    """

    def __init__(self, *, env: dict[str, str] | None = None,
                 stop_timeout: float = STOP_TIMEOUT_S, stream: TextIO | None = None) -> None:
        self.env = node_env(env)
        self.stop_timeout = stop_timeout
        self.stream = stream if stream is not None else sys.stdout
        self.children: list[Child] = []
        self.signals: list[int] = []        # signals received while handling them
        self._write_lock = threading.Lock()
        self._preexec = _parent_death_signal()

    # output ---------------------------------------------------------------------------------

    def say(self, text: str, name: str = 'launch') -> None:
        """Print ``text`` line by line, each prefixed with ``[name]``."""
        with self._write_lock:
            for line in text.splitlines() or ['']:
                self.stream.write(f'[{name}] {line}\n')
            self.stream.flush()

    def _pump(self, child: Child) -> None:
        assert child.proc.stdout is not None
        for raw in iter(child.proc.stdout.readline, b''):
            self.say(raw.decode('utf-8', 'replace').rstrip('\r\n'), child.name)
        child.proc.stdout.close()

    # children -------------------------------------------------------------------------------

    def start(self, name: str, argv: Sequence[str], *, required: bool = True,
              cwd: str | None = None) -> Child:
        """Start ``argv`` as child ``name`` (stdout and stderr merged, prefixed, ours)."""
        if any(c.name == name for c in self.children):
            raise LaunchError(f'a child named {name!r} exists already')
        try:
            proc = subprocess.Popen([str(a) for a in argv], env=self.env, cwd=cwd,
                                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, start_new_session=True,
                                    preexec_fn=self._preexec)
        except OSError as exc:
            raise LaunchError(f'cannot start {name} ({argv[0]}): {exc.strerror}') from exc
        child = Child(name, [str(a) for a in argv], proc, required)
        child.reader = threading.Thread(target=self._pump, args=(child,), daemon=True,
                                        name=f'output-{name}')
        child.reader.start()
        self.children.append(child)
        return child

    def check(self) -> None:
        """Raise ``Interrupted`` after a signal, ``ChildExited`` when a required child ended."""
        if self.signals:
            raise Interrupted(self.signals[0])
        for child in self.children:
            code = child.returncode
            if code is not None and child.required:
                raise ChildExited(child.name, code)

    def wait(self, until: Callable[[], Any] | None = None, *, timeout: float | None = None,
             what: str = 'the condition', every: float = 0.0) -> Any:
        """Poll until ``until()`` is truthy (returned), watching children and signals.

        Without ``until``, waits for every child to end.  ``until`` is asked at most every
        ``every`` seconds (a costly question); children and signals are watched every
        ``POLL_S`` all the same.  Raises ``LaunchError`` after ``timeout`` seconds,
        ``ChildExited`` / ``Interrupted`` as ``check`` does.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        next_ask = -math.inf
        while True:
            if until is None:
                if self.signals:
                    raise Interrupted(self.signals[0])
                if all(c.returncode is not None for c in self.children):
                    return True
            else:
                self.check()
                if time.monotonic() >= next_ask:
                    next_ask = time.monotonic() + every
                    value = until()
                    if value:
                        return value
            if deadline is not None and time.monotonic() > deadline:
                raise LaunchError(f'timed out after {timeout:g} s waiting for {what}')
            time.sleep(POLL_S)

    def stop(self) -> dict[str, int | None]:
        """Stop every running child: SIGINT, then SIGTERM, then SIGKILL; their exit codes."""
        steps = ((signal.SIGINT, self.stop_timeout), (signal.SIGTERM, self.stop_timeout),
                 (signal.SIGKILL, self.stop_timeout))
        for k, (signum, timeout) in enumerate(steps):
            running = [c for c in self.children if c.returncode is None]
            if not running:
                break
            if k:
                self.say(f'{", ".join(c.name for c in running)} still running: '
                         f'{signal.Signals(signum).name}')
            for child in running:
                child.signal(signum)
            deadline = time.monotonic() + timeout
            signals_before = len(self.signals)
            while any(c.returncode is None for c in running) and time.monotonic() < deadline:
                if len(self.signals) > signals_before and signum != signal.SIGKILL:
                    break   # Ctrl-C again: escalate now
                time.sleep(POLL_S)
        for child in self.children:
            if child.reader is not None:
                child.reader.join(timeout=2.0)
        return {c.name: c.returncode for c in self.children}

    @contextlib.contextmanager
    def handle_signals(self) -> Iterator[None]:
        """Turn SIGINT / SIGTERM into ``Interrupted`` at the next ``wait`` / ``check``."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def record(signum: int, frame: Any) -> None:
            self.signals.append(signum)

        old = {s: signal.signal(s, record) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, handler in old.items():
                signal.signal(s, handler)

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def launch_main(argv: Sequence[str] | None, parser: Any,
                run: Callable[[Any, 'Supervisor'], Any],
                report: Callable[['Supervisor', Any], int]) -> int:
    """The body of a launch script's main(): parse, supervise ``run``, ``report`` the result.

    Exit codes as ``sapga_ros.launch.run_launch`` documents them.
    """
    own, ros_args = split_ros_args(argv if argv is not None else sys.argv[1:])
    args = parser.parse_args(own)
    args.ros_args = ros_args
    sup = Supervisor()
    try:
        with sup, sup.handle_signals():
            result = run(args, sup)
    except SapgaError as exc:
        sup.say(f'error: {exc}')
        return exit_code(exc) if isinstance(exc, LaunchError) else 2
    return report(sup, result)


def exit_code(exc: BaseException) -> int:
    """The launcher's exit code for a launch that ended with ``exc``."""
    if isinstance(exc, Interrupted):
        return 128 + exc.signum
    return 1
