"""The body of every node executable's ``main()``: --help, ROS arguments, spin, exit codes.

``run_node(make_node, args, parameters=...)``:

* ``-h`` / ``--help`` among the executable's own arguments (not inside ``--ros-args``):
  print the usage with the node's parameter table (``sim_nodes.params.usage_lines``, from
  the ``Param`` rows the node declares) and exit 0; no ROS context, no node;
* ``rclpy.init``: every ``--params-file`` is checked first (a regular file of at most
  ``MAX_PARAMS_BYTES``, YAML mapping; a value of the node's parameters that its declaration
  refuses is the same one line the node and ``sapga`` print, after the file's name); what
  rcl still refuses (a malformed ``--ros-args``, a params file rcl's parser rejects) is one
  line naming it, not rcl's traceback and log;
* build the node, spin with ``spin_guarded`` (no callback's exception ends the node:
  each is logged as one line), clean shutdown on Ctrl-C, SIGTERM or external shutdown.

Exit codes: 0 done (Ctrl-C, SIGTERM, shutdown, ``--help``); 1 a callback stopped the node
(``NodeExit``); 2 a user error before the node ran (a bad ``--ros-args`` or params file, a
parameter of the wrong type or out of range, an unknown problem, an unusable file): one line
``<executable>: error: ...`` on stderr, no traceback.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import rclpy
import yaml
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.task import Future

from sim_nodes.errors import ConfigError, SapgaError
from sim_nodes.files import load_yaml, read_bounded
from sim_nodes.params import Param, check_mapping, usage_lines
from sim_nodes.ros.guarded import NodeExit, log_failure, one_line, take_exit  # noqa: F401

EXIT_FAILED = 1                        # a callback stopped the node
EXIT_USAGE = 2                         # a user error before the node ran
MAX_PARAMS_BYTES = 16 * 1024 * 1024    # a --params-file larger than this is refused
HELP = ('-h', '--help')
# spin_guarded looks at the context (and a guarded callback's exit request) this often at
# least: rclpy's signal handler shuts the context down without waking an EventsExecutor
WAKE_S = 0.25
PACKAGE = 'sapga_ros'


def spin_guarded(executor: Executor, logger: Any) -> None:
    """Spin ``executor`` until its context shuts down; a callback that raises is logged as
    one line and the executor goes on.  ``NodeExit`` (raised, or requested by a guarded
    callback: ``guarded.py``) and Ctrl-C are raised; a shutdown of the context returns."""
    # The EventsExecutor runs every spin_once's blocked tasks at once (a coroutine waiting for
    # a future would keep a core busy): it spins in windows of WAKE_S instead.
    events = not isinstance(executor, Executor)
    never = Future()
    while executor.context.ok():
        try:
            if events:
                executor.spin_until_future_complete(never, timeout_sec=WAKE_S)
            else:
                executor.spin_once(timeout_sec=WAKE_S)
        except ExternalShutdownException:
            return                  # the EventsExecutor's word for a context shut down
        except (NodeExit, KeyboardInterrupt):
            raise
        except Exception as exc:  # noqa: BLE001 - no callback may end the node
            if not executor.context.ok():
                return
            log_failure(logger, exc)
        exit_request = take_exit(executor)
        if exit_request is not None:
            raise exit_request


# arguments ------------------------------------------------------------------------------------

def own_arguments(argv: Sequence[str]) -> list[str]:
    """The executable's own arguments: those outside ``--ros-args ... [--]``."""
    own, in_ros = [], False
    for arg in argv:
        if arg == '--ros-args':
            in_ros = True
        elif in_ros and arg == '--':
            in_ros = False
        elif not in_ros:
            own.append(arg)
    return own


def params_files(argv: Sequence[str]) -> list[str]:
    """The files of every ``--params-file FILE`` inside ``--ros-args``."""
    files, in_ros = [], False
    for k, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros = True
        elif in_ros and arg == '--':
            in_ros = False
        elif in_ros and arg == '--params-file' and k + 1 < len(argv):
            files.append(argv[k + 1])
    return files


def check_params_file(path: str, table: Sequence[Param] = ()) -> None:
    """``ConfigError`` naming ``path`` unless it is a regular file of YAML holding a mapping
    (rcl would block on a FIFO, and answers a bad file with a traceback) whose values of the
    parameters in ``table`` are ones their declarations accept."""
    try:
        data = read_bounded(path, MAX_PARAMS_BYTES)
    except OSError as exc:
        raise ConfigError(f'--params-file {path}: {exc.strerror or exc}') from None
    try:
        doc = load_yaml(data)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f'--params-file {path}: not valid YAML: '
                          f'{" ".join(str(exc).split())}'[:300]) from None
    if doc is not None and not isinstance(doc, dict):      # None: empty, or comments only
        raise ConfigError(f'--params-file {path}: expected a mapping of node names to '
                          f'ros__parameters, got {type(doc).__name__}')
    known = {p.name for p in table}
    for section in (doc or {}).values():
        values = section.get('ros__parameters') if isinstance(section, dict) else None
        if isinstance(values, dict):       # other nodes' parameters are theirs to check
            check_mapping(table, {k: v for k, v in values.items() if k in known},
                          f'--params-file {path}')


_RCL_WHERE = re.compile(r',? at \S+\.c:\d+')


def rcl_message(exc: BaseException) -> str:
    """rcl's error text without its source locations, on one line."""
    text = _RCL_WHERE.sub('', str(exc)).replace('failed to initialize rcl: ', '')
    return ' '.join(text.split())[:300]


@contextlib.contextmanager
def _stderr_held() -> Iterator[list[bytes]]:
    """Hold what is written to file descriptor 2 (rcl's own log lines); the list gets it."""
    held: list[bytes] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield held
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            held.append(tmp.read())


def init_ros(args: Sequence[str] | None, table: Sequence[Param] = (), **kwargs: Any) -> None:
    """``rclpy.init`` after checking every ``--params-file`` (against ``table``);
    ``ConfigError`` in one line for what rcl refuses (its own log line is dropped)."""
    argv = list(sys.argv if args is None else args)
    for path in params_files(argv):
        check_params_file(path, table)
    with _stderr_held() as held:
        try:
            rclpy.init(args=args, **kwargs)
            failure = None
        except Exception as exc:  # noqa: BLE001 - rcl's RCLError: arguments or params file
            failure = exc
    if failure is not None:
        raise ConfigError(rcl_message(failure)) from None
    if held and held[0]:
        sys.stderr.buffer.write(held[0])        # warnings of a successful init
        sys.stderr.flush()


# --help ---------------------------------------------------------------------------------------

def usage(exe: str, summary: str, table: Sequence[Param]) -> str:
    """The text of ``<exe> --help``."""
    lines = [f'usage: ros2 run {PACKAGE} {exe} [-h] [--ros-args [-p NAME:=VALUE ...] '
             '[--params-file FILE] [-r FROM:=TO ...]]', '', summary, '',
             'Parameters (-p NAME:=VALUE, or a --params-file; examples in '
             f'$(ros2 pkg prefix {PACKAGE})/share/{PACKAGE}/params/):']
    lines += usage_lines(table)
    lines += ['', 'Exit status: 0 stopped (Ctrl-C, SIGTERM); 1 the node failed while running; '
              '2 bad arguments, parameters or files (one line on stderr).']
    return '\n'.join(lines)


def _summary(module: Any) -> str:
    doc = (getattr(module, '__doc__', None) or '').strip()
    return doc.split('\n\n')[0].replace('\n', ' ') if doc else ''


# run ------------------------------------------------------------------------------------------

def _construct(make_node: Callable[[], Node]) -> Node:
    """The node; a publisher or subscription rcl cannot create (two of the node's topics
    resolved to one name with different types, by its parameters or remappings) is a user
    error of one line, not a traceback."""
    try:
        return make_node()
    except _rclpy.RCLError as exc:
        if not rclpy.ok():
            raise            # Ctrl-C while starting up: the context shut down under it
        text = str(exc).split(', at /')[0]
        if 'incompatible type' in text:
            text += (' (two of this node\'s topics resolve to one name: check its topic '
                     'parameters and --ros-args -r remappings)')
        raise SapgaError(text) from None


def run_node(make_node: Callable[[], Node], args: list[str] | None = None,
             executor: Callable[[Node], Executor] | None = None,
             parameters: Callable[[], Sequence[Param]] = tuple, name: str | None = None,
             on_exit: Callable[[], None] | None = None, **init_kwargs: Any) -> int:
    """Run one node the standard way and return the process exit code (module docstring).

    ``executor(node)``: the executor to spin the node on (None: rclpy's global one);
    ``parameters()``: the node's parameter declarations (``--help``, params files);
    ``name``: the executable (default: ``argv[0]``'s);
    ``on_exit``: called before the node is destroyed; ``init_kwargs`` go to ``rclpy.init``.
    A main() is then one line: ``return run_node(lambda: MyNode(), args, parameters=...)``.
    """
    argv = list(sys.argv if args is None else args)
    exe = name or Path(argv[0] if argv else 'node').name
    module = sys.modules.get(getattr(make_node, '__module__', ''), None)
    if any(arg in HELP for arg in own_arguments(argv[1:])):
        print(usage(exe, _summary(module), parameters()))
        return 0
    node = None
    code = 0
    try:
        init_ros(args, parameters(), **init_kwargs)
        node = _construct(make_node)
        ex = executor(node) if executor is not None else rclpy.get_global_executor()
        ex.add_node(node)
        spin_guarded(ex, node.get_logger())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except NodeExit as exc:
        print(f'{exe}: error: {" ".join(str(exc).split())}', file=sys.stderr, flush=True)
        code = EXIT_FAILED
    except (SapgaError, ParameterException) as exc:
        text = ' '.join(str(exc).split())
        print(f'{exe}: error: {text.removeprefix(f"{exe}: ")}'[:1000], file=sys.stderr,
              flush=True)
        code = EXIT_USAGE
    except OSError as exc:
        where = f'{exc.filename}: ' if exc.filename else ''
        print(f'{exe}: error: {where}{exc.strerror or exc}', file=sys.stderr, flush=True)
        code = EXIT_USAGE
    except Exception:  # noqa: BLE001
        if rclpy.ok():
            raise
        # Ctrl-C while starting up: the context was shut down under the constructor
    finally:
        if on_exit is not None:
            on_exit()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
