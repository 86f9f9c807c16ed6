"""What ``sapga launch`` passes through to every node: namespace, remaps, ``--ros-args``.

    sapga launch NAME ... [--namespace NS] [--remap FROM:=TO ...] [--ros-args ARGS...]

* ``--namespace NS``: every node runs in ``/NS`` (``-r __ns:=/NS``), so its relative topics
  and services (all of the contract's but ``/clock`` and ``/diagnostics``) live under it;
  the launch's own node joins it too, so its waits and service calls look there;
* ``--remap FROM:=TO`` (repeatable): a remap rule for every node, the launch's own included;
* ``--ros-args ARGS...``: the rest of the command line goes to every node as it is, after
  the launch's own ROS arguments (e.g. ``--ros-args --log-level debug``).
"""
from __future__ import annotations

import argparse
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

_NAME = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')
_TOKEN = re.compile(r'[~A-Za-z_][A-Za-z0-9_]*|\*\*?|\{node\}')


@dataclass(frozen=True)
class RosOptions:
    """Namespace, remaps and extra ROS arguments of every node of a launch."""

    namespace: str = ''                 # '/robot1'; '' = the root namespace
    remaps: tuple[str, ...] = ()        # 'from:=to' rules
    extra: tuple[str, ...] = ()         # the user's --ros-args tail, as given

    @classmethod
    def of(cls, args: Any) -> RosOptions:
        """The options of parsed launch arguments (none if the parser had no such options)."""
        return cls(namespace=getattr(args, 'namespace', None) or '',
                   remaps=tuple(getattr(args, 'remap', None) or ()),
                   extra=tuple(getattr(args, 'ros_args', None) or ()))

    def rules(self) -> list[str]:
        """``-r`` rules of the namespace and the remaps."""
        rules = [f'__ns:={self.namespace}'] if self.namespace else []
        return rules + list(self.remaps)

    def launch_node_args(self) -> list[str]:
        """``cli_args`` of the launch's own node: the same namespace and remaps."""
        rules = self.rules()
        return ['--ros-args', *(a for rule in rules for a in ('-r', rule))] if rules else []

    def node_args(self, params_file: Path) -> list[str]:
        """The ROS arguments of a node started with ``params_file``."""
        return ['--ros-args', '--params-file', str(params_file),
                *(a for rule in self.rules() for a in ('-r', rule)), *self.extra]

    def service(self, name: str) -> str:
        """A node's service ``node/srv`` as the launch calls it (in the namespace)."""
        return f'{self.namespace}/{name}'


def namespace(text: str) -> str:
    """argparse type: a ROS namespace, given with or without its leading '/'."""
    parts = text.strip('/').split('/')
    if not text.strip('/') or not all(_NAME.fullmatch(p) for p in parts):
        raise argparse.ArgumentTypeError(
            f'{text!r} is not a ROS namespace (names of letters, digits and _, not starting '
            'with a digit, separated by /)')
    return '/' + '/'.join(parts)


def remap(text: str) -> str:
    """argparse type: a remap rule FROM:=TO of topic or service names."""
    source, sep, target = text.partition(':=')
    names = [n for n in (source, target) if n]
    if not sep or len(names) != 2 or not all(
            all(_TOKEN.fullmatch(t) for t in n.strip('/').split('/')) for n in names):
        raise argparse.ArgumentTypeError(f'{text!r} is not a remap rule FROM:=TO of names')
    if source.startswith('__'):
        raise argparse.ArgumentTypeError(
            f'{text!r}: the launch names its nodes itself; use --namespace for __ns')
    return text


def add_ros_arguments(parser: argparse.ArgumentParser) -> None:
    """The pass-through options of every launch (module docstring)."""
    g = parser.add_argument_group('ROS arguments for every node')
    g.add_argument('--namespace', type=namespace, metavar='NS',
                   help='run every node in namespace /NS (their topics and services under it)')
    g.add_argument('--remap', type=remap, action='append', default=[], metavar='FROM:=TO',
                   help='a remap rule for every node (repeatable)')
    parser.epilog = ((parser.epilog + '\n') if parser.epilog else '') + (
        '--ros-args ARGS...: the rest of the command line goes to every node as it is, '
        'e.g. --ros-args --log-level debug')


def split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """The launch's own arguments, and what follows ``--ros-args`` (for the nodes)."""
    argv = list(argv)
    if '--ros-args' not in argv:
        return argv, []
    k = argv.index('--ros-args')
    return argv[:k], argv[k + 1:]
