"""Launch scripts in plain Python: no ``ros2 launch`` needed.

``run_launch(name, argv)`` runs one of ``LAUNCHES`` (``sapga launch NAME args...``):

* ``swingup``: simulator + policy node (a policy file) + MCAP recorder for N episodes;
* ``train_deploy``: trainer node evolves a policy, the policy node loads it over the
  service, the simulator runs the episode in lockstep, the recorder writes MCAP, and the
  ROS episode is compared with the offline evaluation of the served policy.

Every launch takes ``--namespace NS``, ``--remap FROM:=TO`` and a ``--ros-args ...`` tail for
all of its nodes (``ros_args.py``), and works without ``AMENT_PREFIX_PATH`` set (``prefix.py``).
The child processes are started, watched and stopped by ``supervisor.Supervisor``.
"""
from __future__ import annotations

import importlib
import sys
from typing import Sequence

LAUNCHES = {'swingup': 'sapga_ros.launch.swingup',
            'train_deploy': 'sapga_ros.launch.train_deploy'}

USAGE = """usage: sapga launch NAME [options] [--namespace NS] [--remap FROM:=TO ...]
                          [--ros-args ARGS...]

Start a group of nodes as child processes, wait for them and stop them cleanly.

launches:
  swingup       simulator + policy node (a policy file) + recorder for N episodes
  train_deploy  trainer node evolves a policy, the policy node loads it, one recorded episode

sapga launch NAME --help lists the options of a launch.  Every launch passes --namespace,
--remap and the --ros-args tail to all of its nodes.  Exit status: 0 done; 1 a node failed
or the result is wrong; 2 bad arguments; 128 + signal when interrupted."""


def run_launch(name: str, argv: Sequence[str]) -> int:
    """Run launch ``name`` with its arguments; the process exit code.

    0: done; 1: a node failed (named with its exit code) or the launch could not go on;
    2: bad arguments; 128 + signal number: interrupted (130 for Ctrl-C).
    """
    if name in ('-h', '--help'):
        print(USAGE)
        return 0
    if not name:
        print(USAGE.split('\n\n')[0], file=sys.stderr)
        print('sapga launch: error: a launch NAME is required', file=sys.stderr)
        return 2
    if name not in LAUNCHES:
        print(f'sapga launch: error: unknown launch {name!r} (choose from '
              f'{", ".join(LAUNCHES)})', file=sys.stderr)
        return 2
    module = importlib.import_module(LAUNCHES[name])
    return module.main(list(argv))
