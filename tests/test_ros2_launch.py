"""The ``ros2 launch`` files (launch/*.launch.py, installed in share/sapga_ros/launch/): each is
Python that defines ``generate_launch_description``; loaded with the ``launch`` package when
it is importable (ROS 2 installs; not on PyPI, so skipped otherwise), each describes the
package's executables with the parameters the nodes declare."""
from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

import pytest

from sapga_ros.nodes.policy_params import PARAMETERS as POLICY
from sapga_ros.nodes.recorder_params import PARAMETERS as RECORDER
from sapga_ros.nodes.trainer_params import PARAMETERS as TRAINER
from sim_nodes.ros.sim_settings import sim_parameters

LAUNCH_DIR = Path(__file__).resolve().parents[1] / 'launch'
FILES = sorted(LAUNCH_DIR.glob('*.launch.py'))
DECLARED = {'sim_node': {p.name for p in sim_parameters('acrobot')},
            'policy_node': {p.name for p in POLICY},
            'recorder_node': {p.name for p in RECORDER},
            'trainer_node': {p.name for p in TRAINER}}


def test_there_are_launch_files_each_defining_generate_launch_description():
    assert {f.name for f in FILES} >= {'swingup.launch.py', 'train.launch.py'}
    for path in FILES:
        tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
        names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert 'generate_launch_description' in names, path
        assert 'ros2 launch sapga_ros' in (ast.get_docstring(tree) or '')


@pytest.mark.parametrize('path', FILES, ids=lambda p: p.name)
def test_launch_files_set_only_parameters_their_nodes_declare(path):
    """Every ``executable='...'`` is a node executable of the package, and every key of a
    parameter dict is a parameter one of those nodes declares."""
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    exes = {k.value.value for k in ast.walk(tree) if isinstance(k, ast.keyword)
            and k.arg == 'executable' and isinstance(k.value, ast.Constant)}
    assert exes and exes <= set(DECLARED), exes
    declared = set().union(*(DECLARED[e] for e in exes))
    keys = {k.value for d in ast.walk(tree) if isinstance(d, ast.Dict)       # not ARGUMENTS
            and not all(isinstance(v, ast.Tuple) for v in d.values)
            for k in d.keys if isinstance(k, ast.Constant)}
    assert keys and keys <= declared, keys - declared


@pytest.mark.parametrize('path', FILES, ids=lambda p: p.name)
def test_launch_files_load_with_the_launch_package(path):
    pytest.importorskip('launch_ros')       # the ROS 2 launch packages are not on PyPI
    from launch.actions import DeclareLaunchArgument
    from launch_ros.actions import Node

    spec = importlib.util.spec_from_file_location(path.stem.replace('.', '_'), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    arguments = [e for e in description.entities if isinstance(e, DeclareLaunchArgument)]
    nodes = [e for e in description.entities if isinstance(e, Node)]
    assert {a.name for a in arguments} == set(module.ARGUMENTS)
    assert nodes and all(n.node_package == 'sapga_ros' for n in nodes)
    assert {n.node_executable for n in nodes} <= set(DECLARED)
