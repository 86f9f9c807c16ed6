"""The layers of the package, read from the imports with ``ast`` (STYLE: imports point down).

Ranks, lowest first; a module may import from its own rank or a lower one:

0. ``sim_nodes`` - the environment (problem configs, model kernels, goal); never ``sapga_ros``
1. ``sapga_ros.errors``, ``sapga_ros.io`` - typed errors, file primitives, checkpoints
2. ``sapga_ros.policies`` - every policy kind and its file format
3. ``sapga_ros.exemplars``, ``.evaluation``, ``.optim`` - the method core
4. ``sapga_ros.training``, ``.recording``, ``.analysis`` - training runs and experiments;
   recordings; the problems' physical limits
5. ``sapga_ros.nodes``, ``.launch``, ``sim_nodes.ros`` - ROS shells
6. ``sapga_ros.cli``, ``.bench``, ``.viz`` - applications

ROS (``rclpy`` and message packages) is imported only from rank 5 up; ``sim_nodes.ros``
imports nothing from ``sapga_ros`` either.  Every import counts, also one inside a function.
"""
from __future__ import annotations

import ast
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('sim_nodes', 'sapga_ros')
RANKS = {
    'sim_nodes.ros': 5,
    'sim_nodes': 0,
    'sapga_ros.errors': 1, 'sapga_ros.io': 1,
    'sapga_ros.policies': 2,
    'sapga_ros.exemplars': 3, 'sapga_ros.evaluation': 3, 'sapga_ros.optim': 3,
    'sapga_ros.training': 4, 'sapga_ros.recording': 4, 'sapga_ros.analysis': 4,
    'sapga_ros.gym': 4,
    'sapga_ros.nodes': 5, 'sapga_ros.launch': 5,
    'sapga_ros.cli': 6, 'sapga_ros.bench': 6, 'sapga_ros.viz': 6,
    'sapga_ros': 1,  # the package itself: __version__
}
ROS_RANK = 5
ROS_MODULES = ('rclpy', 'rcl_interfaces', 'rosgraph_msgs', 'sensor_msgs', 'std_msgs',
               'std_srvs', 'diagnostic_msgs', 'visualization_msgs', 'geometry_msgs',
               'builtin_interfaces')


def rank(module: str) -> int | None:
    """The rank of a module of ours (longest matching prefix), None for other modules."""
    parts = module.split('.')
    for n in range(len(parts), 0, -1):
        prefix = '.'.join(parts[:n])
        if prefix in RANKS:
            return RANKS[prefix]
    return None


def module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root).with_suffix('')
    parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
    return '.'.join(parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in a file."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
            found.extend((node.lineno, f'{node.module}.{alias.name}') for alias in node.names)
    return found


def violations(root: Path) -> list[str]:
    """Every import of the tree under ``root`` that points up a layer, one line each."""
    bad = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob('*.py')):
            me = module_name(root, path)
            my_rank = rank(me)
            for line, target in imports(path):
                where = f'{path.relative_to(root)}:{line}: {me} (rank {my_rank}) imports {target}'
                top = target.split('.')[0]
                if top in ROS_MODULES and my_rank < ROS_RANK:
                    bad.append(f'{where}: ROS below the ROS shells')
                target_rank = rank(target)
                if target_rank is None:
                    continue
                if me.startswith('sim_nodes') and top == 'sapga_ros':
                    bad.append(f'{where}: the environment imports the method')
                elif target_rank > my_rank:
                    bad.append(f'{where} (rank {target_rank}): upward import')
    return bad


def test_every_module_of_ours_has_a_rank():
    """A new folder must be placed in a layer before it can be imported from."""
    for package in PACKAGES:
        for path in (ROOT / package).rglob('*.py'):
            assert rank(module_name(ROOT, path)) is not None, path


def test_imports_point_down_the_layers():
    """No module imports from a layer above its own, and ROS stays in the shells."""
    assert violations(ROOT) == []


def test_a_planted_forbidden_import_is_found(tmp_path):
    """The checker is not vacuous: upward, cross-package and ROS imports are each reported."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package,
                        ignore=shutil.ignore_patterns('__pycache__'))
    assert violations(tmp_path) == []
    planted = {
        'sapga_ros/optim/sapga.py': 'from sapga_ros.cli.main import main\n',
        'sim_nodes/goal.py': 'import sapga_ros.errors\n',
        'sim_nodes/ros/sim_node.py': 'from sapga_ros.nodes import policy_node\n',
        'sapga_ros/evaluation/engine.py': 'def f():\n    import rclpy\n',
    }
    for rel, text in planted.items():
        path = tmp_path / rel
        path.write_text(path.read_text() + '\n' + text)
    found = violations(tmp_path)
    assert {line.split(':')[0] for line in found} == set(planted), found
