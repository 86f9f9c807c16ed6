"""Package build for sapga_ros: an ament_python package that colcon and pip both accept.

Every executable must be found where ``ros2 run`` looks, ``<prefix>/lib/sapga_ros/<exe>``.
The executables are NODES and one simulator ``<model>_sim`` per model module of
sim_nodes/models (``model_simulators``: the models' registry file runs on its own, nothing of
the package is imported).

* ``colcon build`` runs ``setup.py install`` (or ``develop`` with ``--symlink-install``) and
  setup.cfg sends the console scripts straight to ``$base/lib/sapga_ros``.
* A wheel (``pip install .`` and ``pip install -e .``) always puts console scripts in
  ``<prefix>/bin``.  So whenever the scripts do not land in ``lib/sapga_ros``, ``install_data``
  below adds one small launcher per executable under ``lib/sapga_ros`` that execs the
  console script of the same prefix.  The decision is taken from the install locations the
  build actually uses, never from ``sys.argv``, so colcon's scripts are never clobbered.
* setuptools' ``editable_wheel`` skips ``data_files`` altogether: it asks the distribution
  for ``has_data()``, a method that does not exist (it is ``has_data_files()``).  The
  ``editable_wheel`` below supplies it, so an editable install gets the ament index
  marker, package.xml, msg_configs and the launchers like any other install.
"""
import glob
import os
import re
import runpy

from setuptools import find_packages, setup
# setuptools has no install_data of its own; importing setuptools first makes this its distutils
from distutils.command.install_data import install_data as _install_data  # noqa: I100

try:
    from setuptools.command.editable_wheel import editable_wheel as _editable_wheel
except ImportError:  # setuptools < 64 has no PEP 660 editable installs
    _editable_wheel = None

PACKAGE = 'sapga_ros'
HERE = os.path.dirname(os.path.abspath(__file__))
NODES = {
    'sapga': 'sapga_ros.cli.main:main',
    'sim_node': 'sim_nodes.ros.sim_node:main',
    'policy_node': 'sapga_ros.nodes.policy_node:main',
    'trainer_node': 'sapga_ros.nodes.trainer_node:main',
    'recorder_node': 'sapga_ros.nodes.recorder_node:main',
}


def model_simulators():
    """``<model>_sim`` for every model of sim_nodes/models (its registry.py, run on its own)."""
    registry = runpy.run_path(os.path.join(HERE, 'sim_nodes', 'models', 'registry.py'))
    names = (registry['sim_executable'](model) for model in registry['model_names']())
    return {name: f'sim_nodes.ros.sim_node:mains.{name}' for name in names}


def package_version():
    """package.xml's <version>: the one source of the version (sapga_ros.__version__)."""
    with open(os.path.join(HERE, 'package.xml'), encoding='utf-8') as f:
        return re.search(r'<version>\s*([^<\s]+)\s*</version>', f.read()).group(1)


EXECUTABLES = {**NODES, **model_simulators()}
# A launcher lives in <prefix>/lib/sapga_ros; a wheel's console scripts in <prefix>/bin.
LAUNCHER = """#!/bin/sh
# `ros2 run {package} {exe}` entry point: runs the console script of this install prefix.
script="$(dirname "$0")/../../bin/{exe}"
if [ ! -x "$script" ]; then
    echo "{package}: console script not found: $script" >&2
    exit 127
fi
exec "$script" "$@"
"""


def tree_data_files(src, dest, patterns=('*.yaml', '*.yml')):
    """data_files entries installing every file matching patterns under src, subfolders too."""
    by_dir = {}
    for pattern in patterns:
        for path in glob.glob(os.path.join(src, '**', pattern), recursive=True):
            rel_dir = os.path.dirname(os.path.relpath(path, src))
            by_dir.setdefault(os.path.join(dest, rel_dir) if rel_dir else dest, []).append(path)
    return [(d, sorted(files)) for d, files in sorted(by_dir.items())]


def write_launchers(directory):
    """Write the lib/sapga_ros launchers into directory; return their paths."""
    os.makedirs(directory, exist_ok=True)
    paths = []
    for exe in sorted(EXECUTABLES):
        path = os.path.join(directory, exe)
        with open(path, 'w', encoding='utf-8') as f:
            f.write(LAUNCHER.format(package=PACKAGE, exe=exe))
        os.chmod(path, 0o755)
        paths.append(path)
    return paths


class install_data(_install_data):  # noqa: N801 (distutils command naming)
    """install_data that adds lib/sapga_ros launchers when console scripts go elsewhere."""

    def finalize_options(self):
        super().finalize_options()
        install = self.get_finalized_command('install')
        scripts_dir = os.path.normpath(os.path.abspath(install.install_scripts))
        ros2run_dir = os.path.normpath(os.path.abspath(
            os.path.join(self.install_dir, 'lib', PACKAGE)))
        if scripts_dir != ros2run_dir:
            build_temp = self.get_finalized_command('build').build_temp
            launchers = write_launchers(os.path.join(build_temp, 'ros2run'))
            self.data_files = list(self.data_files or []) + [('lib/' + PACKAGE, launchers)]


cmdclass = {'install_data': install_data}

if _editable_wheel is not None:
    class editable_wheel(_editable_wheel):  # noqa: N801 (distutils command naming)
        """editable_wheel that installs data_files (setuptools looks for has_data())."""

        def run(self):
            dist = self.distribution
            if not callable(getattr(dist, 'has_data', None)):
                dist.has_data = dist.has_data_files
            super().run()

    cmdclass['editable_wheel'] = editable_wheel

data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
    ('share/' + PACKAGE, ['package.xml']),
    # problems, node parameters, experiments, the Foxglove layouts (foxglove/<problem>.json)
    *tree_data_files('msg_configs', 'share/' + PACKAGE + '/msg_configs',
                     ('*.yaml', '*.yml', '*.json')),
    # the nodes' parameter files also where ROS users look: share/sapga_ros/params/<exe>.yaml
    *tree_data_files(os.path.join('msg_configs', 'params'), 'share/' + PACKAGE + '/params'),
    # `ros2 launch sapga_ros <name>.launch.py` (the plain-Python launches: `sapga launch`)
    *tree_data_files('launch', 'share/' + PACKAGE + '/launch', ('*.launch.py',)),
]

setup(
    name=PACKAGE,
    version=package_version(),
    packages=find_packages(include=['sapga_ros', 'sapga_ros.*', 'sim_nodes', 'sim_nodes.*']),
    data_files=data_files,
    cmdclass=cmdclass,
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='sapga_ros maintainers',
    maintainer_email='sapga@example.com',
    description='Exemplar-based policy search (SAP-GA) for pendulums, with ROS 2 nodes',
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': [f'{exe} = {target}' for exe, target in sorted(EXECUTABLES.items())],
    },
)
