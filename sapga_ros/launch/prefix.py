"""Where this package is installed, so ``sapga`` works without ``AMENT_PREFIX_PATH`` set.

ROS finds packages (rclpy's middleware, message definitions, ``ros2 run``'s executables)
through the prefixes listed in ``AMENT_PREFIX_PATH``.  A venv or ``pip install --prefix``
install of sapga_ros is such a prefix (``share/ament_index/resource_index/packages/
sapga_ros``), and so is a colcon install's ``install/sapga_ros``; ``own_prefixes`` finds
it from where the running ``sapga`` lives (``<prefix>/bin/sapga`` or
``<prefix>/lib/sapga_ros/sapga``), from ``sys.prefix`` and from the installed package
(``<prefix>/lib/pythonX.Y/site-packages/sapga_ros``).  ``ensure_ament_prefix`` puts the
prefixes found in front of ``AMENT_PREFIX_PATH`` of this process, and so of every node the
launches start, unless one already listed holds the package.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = 'sapga_ros'
MARKER = Path('share', 'ament_index', 'resource_index', 'packages')


def holds_package(prefix: str | os.PathLike, package: str = PACKAGE) -> bool:
    """Whether ``prefix`` is an ament prefix with ``package`` in its index."""
    return (Path(prefix) / MARKER / package).is_file()


def _candidates(argv0: str) -> list[Path]:
    found = []
    if argv0:
        script = Path(os.path.abspath(argv0))
        found += [script.parents[k] for k in (1, 2) if len(script.parents) > k]
    package = Path(__file__).resolve().parents[1]         # .../site-packages/sapga_ros
    found += [package.parents[k] for k in (2, 3) if len(package.parents) > k]
    found.append(Path(sys.prefix))
    return found


def own_prefixes(argv0: str | None = None) -> list[str]:
    """The ament prefixes of this install: the one holding sapga_ros, and this Python's
    prefix if it is an ament prefix too (a venv of pip-installed ROS packages)."""
    argv0 = sys.argv[0] if argv0 is None else argv0
    prefixes: list[str] = []
    for path in _candidates(argv0):
        path = Path(os.path.normpath(path))
        if holds_package(path) and str(path) not in prefixes:
            prefixes.append(str(path))
            break
    if (Path(sys.prefix) / MARKER).is_dir() and sys.prefix not in prefixes:
        prefixes.append(sys.prefix)
    return prefixes


def ensure_ament_prefix(env: dict[str, str] | None = None) -> list[str]:
    """Put this install's prefixes in front of ``AMENT_PREFIX_PATH`` of ``env`` (default:
    this process) unless a listed prefix holds sapga_ros already; the prefixes added."""
    env = os.environ if env is None else env
    listed = [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    if any(holds_package(p) for p in listed):
        return []
    added = [p for p in own_prefixes() if p not in listed]
    if added:
        env['AMENT_PREFIX_PATH'] = os.pathsep.join([*added, *listed])
    return added
