"""The layer checker that ``test_layers.py`` runs (and plants violations for): every import
of a source tree read with ``ast``, resolved to an absolute module name, and judged.

Ranks, lowest first; a module may import from its own rank or a lower one:

0. ``sim_nodes`` - the environment (problem configs, model kernels, goal); never ``sapga_ros``
1. ``sapga_ros.errors``, ``sapga_ros.io`` - typed errors, file primitives, checkpoints
2. ``sapga_ros.policies`` - every policy kind with its file format
3. ``sapga_ros.exemplars``, ``.evaluation``, ``.optim`` - the method core
4. ``sapga_ros.training``, ``.recording``, ``.analysis``, ``.gym`` - training runs and
   experiments; recordings; the problems' physical limits; Gymnasium environments
5. ``sapga_ros.nodes``, ``.launch``, ``sim_nodes.ros`` - ROS shells
6. ``sapga_ros.cli``, ``.bench``, ``.viz`` - applications

What counts as an import: ``import a.b``, ``from a import b`` (also relative ones, resolved
against the importing module's package), and ``importlib.import_module(...)`` /
``__import__(...)`` calls whose argument is a string constant, an f-string with a constant
package prefix (``f'sim_nodes.models.{name}'`` imports from ``sim_nodes.models``), or a
module-level constant dict, list or tuple of names (every value counts).  An import inside a
function counts like one at the top.  A dynamic import the checker cannot resolve is
refused below the ROS shells (it could hide anything); in the shells it loads ROS message
types by name.

What is ROS (``is_ros``): a top-level module that the ament resource index of an install
prefix lists as a package, or whose installed distribution is a ROS wheel (named
``ros-...``), or whose name follows ROS's conventions (``rclpy``, ``rcl_*``, ``rmw*``,
``rosidl_*``, ``rosbag2*``, ``tf2*``, ``ament_*``, ``*_msgs``, ``*_srvs``,
``*_interfaces``) so that a package not installed here is caught too.  Our own packages are
never ROS.

An import cycle among modules of one rank is refused too: it makes two modules one (a
cycle across ranks holds an upward import, reported as such).

Over 300 lines on purpose: reading the imports, telling ROS and finding the cycles are one
checker, which the tests plant violations against as a whole.
"""
from __future__ import annotations

import ast
import functools
import importlib.metadata
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

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
}
# ranks of a module itself, not of the modules below it: a new folder of sapga_ros must be
# placed in a layer (sim_nodes is the environment through and through, its ros/ apart)
EXACT_RANKS = {'sapga_ros': 1}  # the package itself: __version__
ROS_RANK = 5
ROS_NAMES = re.compile(r'^(rclpy|rcl|rcl_.*|rmw.*|rosidl.*|rosbag2.*|tf2.*|ament_.*|ros2.*'
                       r'|launch_ros|.*_msgs|.*_srvs|.*_interfaces)$')
DYNAMIC = {'import_module', '__import__'}
UNRESOLVED = '<dynamic>'


def rank(module: str) -> int | None:
    """The rank of a module of ours (longest matching prefix), None for other modules and
    for a module of ours that no layer holds."""
    if module in EXACT_RANKS:
        return EXACT_RANKS[module]
    parts = module.split('.')
    for n in range(len(parts), 0, -1):
        prefix = '.'.join(parts[:n])
        if prefix in RANKS:
            return RANKS[prefix]
    return None


def ament_packages(prefixes: list[Path] | None = None) -> set[str]:
    """The packages the ament resource index lists under ``prefixes`` (default: every prefix
    of ``AMENT_PREFIX_PATH`` and this Python's own prefix)."""
    if prefixes is None:
        prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
                    if p] + [Path(sys.prefix)]
    found = set()
    for prefix in prefixes:
        index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
        if index.is_dir():
            found.update(p.name for p in index.iterdir())
    return found


def ros_wheel_modules() -> set[str]:
    """Top-level modules that an installed ROS wheel (a distribution named ``ros-...``)
    provides."""
    return {module for module, dists in importlib.metadata.packages_distributions().items()
            if any(d.lower().startswith('ros-') for d in dists)}


@dataclass(frozen=True)
class RosRule:
    """Which top-level modules are ROS packages (the module docstring gives the rule)."""

    ament: frozenset[str]
    wheels: frozenset[str]

    @classmethod
    def here(cls, prefixes: list[Path] | None = None) -> RosRule:
        return cls(frozenset(ament_packages(prefixes)), frozenset(ros_wheel_modules()))

    def is_ros(self, top: str) -> bool:
        if top in PACKAGES:
            return False
        return top in self.ament or top in self.wheels or bool(ROS_NAMES.match(top))


@functools.lru_cache(maxsize=1)
def _rule_here() -> RosRule:
    return RosRule.here()


def module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root).with_suffix('')
    parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
    return '.'.join(parts)


def _relative(package: str, level: int, name: str | None) -> str:
    """``from <level dots><name>`` resolved against ``package``."""
    base = package.split('.') if package else []
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return '.'.join(base + ([name] if name else []))


def _constants(tree: ast.Module) -> dict[str, list[str]]:
    """Module-level names bound to a string, or a dict / list / tuple of strings."""
    found = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name):
            value = node.value
            items = (value.values if isinstance(value, ast.Dict)
                     else value.elts if isinstance(value, (ast.List, ast.Tuple)) else [value])
            strings = [v.value for v in items
                       if isinstance(v, ast.Constant) and isinstance(v.value, str)]
            if strings and len(strings) == len(items):
                found[node.targets[0].id] = strings
    return found


def _dynamic_targets(arg: ast.expr, constants: dict[str, list[str]]) -> list[str]:
    """What a dynamic import's argument names; ``[UNRESOLVED]`` when it cannot be read."""
    if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return [arg.value]
    if isinstance(arg, ast.JoinedStr) and arg.values \
            and isinstance(arg.values[0], ast.Constant) and '.' in arg.values[0].value:
        return [arg.values[0].value.rpartition('.')[0]]
    if isinstance(arg, ast.Subscript):
        arg = arg.value
    if isinstance(arg, ast.Name) and arg.id in constants:
        return constants[arg.id]
    return [UNRESOLVED]


def _is_dynamic_import(call: ast.Call) -> bool:
    func = call.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, 'id', None)
    return name in DYNAMIC and bool(call.args)


def imports(path: Path, me: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file of module ``me``."""
    return list(_imports(path.read_text(encoding='utf-8'), str(path), me,
                         path.name == '__init__.py'))


@functools.lru_cache(maxsize=None)
def _imports(text: str, where: str, me: str, is_package: bool) -> tuple[tuple[int, str], ...]:
    tree = ast.parse(text, where)
    package = me if is_package else me.rpartition('.')[0]
    constants = _constants(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _relative(package, node.level, node.module) if node.level else node.module
            found.append((node.lineno, base))
            found.extend((node.lineno, f'{base}.{alias.name}') for alias in node.names
                         if alias.name != '*')
        elif isinstance(node, ast.Call) and _is_dynamic_import(node):
            anchor = _anchor(node, package)
            for target in _dynamic_targets(node.args[0], constants):
                if target.startswith('.'):
                    level = len(target) - len(target.lstrip('.'))
                    target = (_relative(anchor, level, target.lstrip('.') or None)
                              if anchor is not None else UNRESOLVED)
                found.append((node.lineno, target))
    return tuple(found)


def _anchor(call: ast.Call, package: str) -> str | None:
    """The package a relative ``import_module(name, package)`` starts from."""
    args = list(call.args[1:2]) + [k.value for k in call.keywords if k.arg == 'package']
    if not args:
        return None
    arg = args[0]
    if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return arg.value
    if isinstance(arg, ast.Name) and arg.id == '__package__':
        return package
    return None


def _modules(root: Path) -> dict[str, Path]:
    return {module_name(root, path): path
            for package in PACKAGES for path in sorted((root / package).rglob('*.py'))}


def _own_module(target: str, modules: dict[str, Path]) -> str | None:
    """The module of ours that an import target names (``a.b.func`` -> ``a.b``)."""
    parts = target.split('.')
    for n in range(len(parts), 0, -1):
        prefix = '.'.join(parts[:n])
        if prefix in modules:
            return prefix
    return None


def violations(root: Path, ros: RosRule | None = None) -> list[str]:
    """Every import of the tree under ``root`` that breaks a layer rule, one line each."""
    ros = ros or _rule_here()
    modules = _modules(root)
    bad, graph = [], {me: {} for me in modules}
    for me, path in modules.items():
        my_rank = rank(me)
        if my_rank is None:
            bad.append(f'{path.relative_to(root)}: {me} has no rank (add it to RANKS)')
            continue
        for line, target in imports(path, me):
            where = f'{path.relative_to(root)}:{line}: {me} (rank {my_rank}) imports {target}'
            top = target.split('.')[0]
            if target == UNRESOLVED:
                if my_rank < ROS_RANK:
                    bad.append(f'{where}: a dynamic import the layer test cannot resolve')
                continue
            if my_rank < ROS_RANK and ros.is_ros(top):
                bad.append(f'{where}: ROS below the ROS shells')
            env_imports_method = me.startswith('sim_nodes') and top == 'sapga_ros'
            if env_imports_method:
                bad.append(f'{where}: the environment imports the method')
            own = _own_module(target, modules)
            if own is None or own == me:
                continue
            graph[me].setdefault(own, line)
            target_rank = rank(own)
            if not env_imports_method and target_rank is not None and target_rank > my_rank:
                bad.append(f'{where} (rank {target_rank}): upward import')
    same_rank = [c for c in cycles(graph) if len({rank(m) for m in c}) == 1]
    return bad + [_cycle_line(root, modules, graph, cycle) for cycle in same_rank]


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """One cycle (a list of modules, the first repeated at the end) for every group of
    modules that import each other (a strongly connected component, Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(set(group))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return [_path_through(graph, sorted(group)[0], group) for group in groups]


def _path_through(graph: dict[str, dict[str, int]], start: str, group: set[str]) -> list[str]:
    """A shortest cycle from ``start`` back to it inside ``group`` (breadth first)."""
    came = {start: None}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph[v]):
            if w == start:
                path = [v]
                while came[path[-1]] is not None:
                    path.append(came[path[-1]])
                return path[::-1] + [start]
            if w in group and w not in came:
                came[w] = v
                queue.append(w)
    raise AssertionError(f'no cycle through {start}')


def _cycle_line(root: Path, modules: dict[str, Path], graph: dict[str, dict[str, int]],
                cycle: list[str]) -> str:
    first = cycle[0]
    steps = ' -> '.join(f'{a} (line {graph[a][b]})' for a, b in zip(cycle, cycle[1:]))
    return f'{modules[first].relative_to(root)}:{graph[first][cycle[1]]}: import cycle ' \
           f'{steps} -> {first}'
