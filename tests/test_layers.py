"""The layers of the package, read from the imports with ``ast`` (STYLE: imports point down).

The ranks and the rules are in ``tests/layers.py``.  Every rule is shown to fail: a
violation of it is planted in a copy of the source tree and must be reported, naming the
planted file.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from layers import (PACKAGES, ROS_RANK, RosRule, cycles, module_name, rank, ros_wheel_modules,
                    violations)

ROOT = Path(__file__).resolve().parents[1]


def test_every_module_of_ours_has_a_rank():
    """A new folder must be placed in a layer before it can be imported from."""
    unranked = [path for package in PACKAGES for path in (ROOT / package).rglob('*.py')
                if rank(module_name(ROOT, path)) is None]
    assert unranked == []


def test_imports_point_down_the_layers():
    """No module imports from a layer above its own, ROS stays in the shells, no cycles."""
    assert violations(ROOT) == []


@pytest.fixture
def tree(tmp_path):
    """A copy of the source tree to plant violations in (clean before planting)."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package,
                        ignore=shutil.ignore_patterns('__pycache__'))
    assert violations(tmp_path) == []
    return tmp_path


def plant(root: Path, rel: str, text: str) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.exists() else ''
    path.write_text(old + '\n' + text)


PLANTED = [  # (file, text appended, what the report says)
    ('sapga_ros/optim/sapga.py', 'from sapga_ros.cli.main import main\n', 'upward import'),
    ('sim_nodes/goal.py', 'import sapga_ros.errors\n', 'the environment imports the method'),
    ('sim_nodes/ros/sim_node.py', 'from sapga_ros.nodes import policy_node\n',
     'the environment imports the method'),
    ('sapga_ros/evaluation/engine.py', 'def f():\n    import rclpy\n', 'ROS below'),
    # relative imports, resolved against the module's package
    ('sapga_ros/optim/operators.py', 'from ..viz import report\n', 'upward import'),
    ('sapga_ros/io/atomic.py', 'from ..training.loop import train\n', 'upward import'),
    ('sapga_ros/training/__init__.py', 'from .. import launch\n', 'upward import'),
    # importlib and __import__: constants, f-strings, module-level tables, relative names
    ('sapga_ros/recording/events.py', 'import importlib\n'
     "importlib.import_module('sapga_ros.launch.swingup')\n", 'upward import'),
    ('sapga_ros/analysis/limit.py', "def f(x):\n    return __import__(f'sapga_ros.cli.{x}')\n",
     'upward import'),
    ('sapga_ros/exemplars/styles.py', "WHERE = {'a': 'sapga_ros.bench.batch'}\n"
     'def f(k):\n    import importlib\n    return importlib.import_module(WHERE[k])\n',
     'upward import'),
    ('sapga_ros/exemplars/distance.py', 'from importlib import import_module\n'
     "import_module('..nodes', 'sapga_ros.exemplars')\n", 'upward import'),
    ('sapga_ros/evaluation/evaluator.py', 'import importlib\n'
     "importlib.import_module('..gym', __package__)\n", 'upward import'),
    ('sapga_ros/evaluation/state_selector.py', 'import importlib\n'
     "importlib.import_module('.x', package=some_package())\n", 'cannot resolve'),
    ('sapga_ros/io/bounded.py', 'def f(name):\n    return __import__(name)\n',
     'cannot resolve'),
    ('sim_nodes/models/common.py', "__import__('std_srvs.srv')\n", 'ROS below'),
    # ROS packages that are not installed here, known by their names
    ('sapga_ros/recording/chunks.py', 'import rosbag2_py\n', 'ROS below'),
    ('sapga_ros/optim/base.py', 'from nav_msgs.msg import Odometry\n', 'ROS below'),
    ('sapga_ros/gym/env.py', 'import tf2_ros\n', 'ROS below'),
    ('sim_nodes/reference.py', 'from example_interfaces.srv import AddTwoInts\n',
     'ROS below'),
]


def test_every_planted_forbidden_import_is_found(tree):
    """The checker is not vacuous: each kind of forbidden import, planted in its own file,
    is reported, naming that file and what is wrong (one copy of the tree holds them all)."""
    for rel, text, _ in PLANTED:
        plant(tree, rel, text)
    found: dict[str, list[str]] = {}
    for line in violations(tree):
        found.setdefault(line.split(':')[0], []).append(line)
    assert set(found) == {rel for rel, _, _ in PLANTED}, found
    for rel, _, reason in PLANTED:
        assert all(reason in line for line in found[rel]), found[rel]


def test_ros_imports_are_allowed_in_the_shells(tree):
    """The same ROS imports one rank up, in the shells, are no violation (the rule is the
    rank, not the name)."""
    plant(tree, 'sapga_ros/nodes/policy_node.py', 'import rosbag2_py\nimport tf2_ros\n')
    plant(tree, 'sim_nodes/ros/common.py', 'from nav_msgs.msg import Odometry\n')
    assert rank('sapga_ros.nodes.policy_node') == ROS_RANK
    assert violations(tree) == []


def test_a_ros_package_is_known_by_the_ament_index_without_a_telling_name(tree):
    """A package the ament resource index lists is ROS, whatever its name."""
    prefix = tree / 'prefix'
    index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True)
    (index / 'warehouse_driver').write_text('')
    plant(tree, 'sapga_ros/training/loop.py', 'import warehouse_driver\n')
    assert violations(tree, RosRule.here([prefix])) != []
    assert violations(tree, RosRule.here([])) == []


def test_a_ros_package_is_known_by_its_ros_wheel(tree, monkeypatch):
    """A module that an installed ROS wheel (``ros-...``) provides is ROS, whatever its name;
    the shared venv's rclpy and message packages are such wheels."""
    site = tree / 'site'
    info = site / 'ros_warehouse_planner-1.0.dist-info'
    info.mkdir(parents=True)
    (info / 'METADATA').write_text('Metadata-Version: 2.1\nName: ros-warehouse-planner\n'
                                   'Version: 1.0\n')
    (info / 'top_level.txt').write_text('warehouse_planner\n')
    assert 'warehouse_planner' not in ros_wheel_modules()
    monkeypatch.syspath_prepend(str(site))
    assert 'warehouse_planner' in ros_wheel_modules()
    plant(tree, 'sapga_ros/analysis/limit.py', 'import warehouse_planner\n')
    found = violations(tree, RosRule.here([]))
    assert len(found) == 1 and 'ROS below' in found[0], found


def test_the_rule_tells_ros_from_plain_libraries():
    """The ROS packages the shells use are ROS, however installed (wheels or an ament
    prefix); our packages, rosbags, mcap and numpy are not."""
    rule = RosRule.here()
    assert all(rule.is_ros(m) for m in ('rclpy', 'std_msgs', 'rcl_interfaces',
                                        'ament_index_python', 'rosbag2_py', 'tf2_ros'))
    assert not any(rule.is_ros(m) for m in ('sapga_ros', 'sim_nodes', 'rosbags', 'mcap',
                                            'mcap_ros2', 'numpy', 'yaml'))


def test_a_same_rank_import_cycle_is_refused(tree):
    """Two modules of one rank that import each other, even inside a function, are one
    module split in two: the cycle is reported with the lines that close it."""
    plant(tree, 'sapga_ros/optim/operators.py', 'def f():\n    from . import sapga\n')
    found = violations(tree)
    assert len(found) == 1 and 'import cycle' in found[0], found
    assert 'sapga_ros.optim.operators' in found[0] and 'sapga_ros.optim.sapga' in found[0]


def test_a_longer_cycle_is_found_once():
    graph = {'a': {'b': 1}, 'b': {'c': 2}, 'c': {'a': 3, 'd': 4}, 'd': {}, 'e': {'e': 5}}
    assert cycles(graph) == [['a', 'b', 'c', 'a']]


def test_a_module_outside_every_layer_is_refused(tree):
    """A new room of sapga_ros that no rank holds fails both the rank test's rule and the
    checker."""
    plant(tree, 'sapga_ros/newroom/__init__.py', '')
    plant(tree, 'sapga_ros/stray.py', 'X = 1\n')
    assert rank('sapga_ros.newroom') is None and rank('sapga_ros.stray') is None
    found = violations(tree)
    assert {line.split(':')[0] for line in found} == {'sapga_ros/newroom/__init__.py',
                                                      'sapga_ros/stray.py'}, found
