"""sapga_ros: exemplar-based policy search (SAP-GA) for pendulums, with ROS 2 nodes.

Layers, lowest first (``tests/test_layers.py`` keeps imports pointing down; docs/architecture.md):
``errors``/``io`` (file primitives), the method core (``exemplars``, ``evaluation``,
``optim``; numpy and numba, never rclpy), ``training`` and ``recording``, the ROS shells
(``nodes``, ``launch``), and the applications (``cli``, ``bench``, ``viz``).  The
environment (problem configs, model kernels, the simulator node) is the ``sim_nodes``
package below all of them.

``__version__`` is package.xml's ``<version>``, the one source: setup.py installs the
distribution with it, and a source tree without an install reads it from package.xml.
"""
from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

DISTRIBUTION = 'sapga_ros'


def version_of_package_xml(path: Path) -> str | None:
    """The ``<version>`` of a package.xml, or None."""
    try:
        found = re.search(r'<version>\s*([^<\s]+)\s*</version>', path.read_text('utf-8'))
    except OSError:
        return None
    return found.group(1) if found else None


@lru_cache(maxsize=None)
def package_version() -> str:
    """This package's version: the source tree's package.xml if there is one (a checkout,
    an editable install), else the installed distribution's (from package.xml too)."""
    source = version_of_package_xml(Path(__file__).resolve().parents[1] / 'package.xml')
    if source:
        return source
    from importlib import metadata
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return 'unknown'


def __getattr__(name: str) -> str:
    if name == '__version__':
        return package_version()
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
