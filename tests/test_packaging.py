"""Packaging: `ros2 run sapga_ros <exe>` finds every executable in every way of installing.

`ros2 run` looks for ``<prefix>/lib/sapga_ros/<exe>``, where ``<prefix>`` is the package's
ament prefix.  Three installs must provide it: the editable install in the project venv
(`make venv`), a plain ``pip install`` (a wheel: console scripts in ``<prefix>/bin`` and
launchers in ``lib/sapga_ros``) and ``colcon build`` (console scripts in ``lib/sapga_ros``).
Each also installs the node parameter files under ``share/sapga_ros/params/``.
"""
import ast
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from sim_nodes.models.registry import model_names, sim_executable

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'sapga_ros'
# what a source checkout of the package is; build outputs, .git and .venv stay behind
PACKAGE_FILES = ('package.xml', 'setup.py', 'setup.cfg', 'resource', 'sapga_ros', 'sim_nodes',
                 'msg_configs', 'launch')
IGNORED = shutil.ignore_patterns('__pycache__', '*.pyc', '*.egg-info', 'build', 'install',
                                 'log')
TIMEOUT = 300  # [s] for one build or one `--help` on a loaded machine


def _executables() -> list[str]:
    """setup.py's executables: its NODES literal and one simulator per model (registry)."""
    tree = ast.parse((REPO / 'setup.py').read_text(encoding='utf-8'))
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and getattr(node.targets[0], 'id', None) == 'NODES'):
            return [*ast.literal_eval(node.value), *map(sim_executable, model_names())]
    raise AssertionError('setup.py defines no NODES dict')


EXECUTABLES = sorted(_executables())


def _config_files() -> list[Path]:
    """Every YAML and JSON file (the Foxglove layout) under msg_configs/, relative to it,
    subfolders included."""
    root = REPO / 'msg_configs'
    return sorted(p.relative_to(root) for p in root.rglob('*')
                  if p.suffix in ('.yaml', '.yml', '.json') and p.is_file())


def _params_files() -> list[str]:
    """The node parameter files, installed under share/sapga_ros/params/ too."""
    return sorted(p.name for p in (REPO / 'msg_configs' / 'params').glob('*.yaml'))


def _assert_params_installed(share: Path) -> None:
    """Every node parameter file is in ``share``/params, where ROS users look."""
    missing = [name for name in _params_files() if not (share / 'params' / name).is_file()]
    assert not missing, f'not installed in {share}/params: {missing}'


def _package_xml_version() -> str:
    text = (REPO / 'package.xml').read_text(encoding='utf-8')
    return text.split('<version>')[1].split('</version>')[0].strip()


def _is_executable_file(path: Path) -> bool:
    return path.is_file() and os.access(path, os.X_OK)


def _env(**overrides: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE='1')
    env.update(overrides)
    return env


def _run(cmd: list, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True,
                          timeout=TIMEOUT, **kwargs)


def _assert_ok(proc: subprocess.CompletedProcess, what: str) -> None:
    assert proc.returncode == 0, (
        f'{what} exited {proc.returncode}\n--- stdout\n{proc.stdout[-4000:]}'
        f'\n--- stderr\n{proc.stderr[-4000:]}')


def _assert_simulators_start(lib: Path, env: dict[str, str]) -> None:
    """Every simulator executable in ``lib`` reaches its node (``sim_nodes.ros.sim_node:
    mains.<model>_sim`` resolves), which refuses an unknown problem with exit 2."""
    for exe in (e for e in EXECUTABLES if e.endswith('_sim') or e == 'sim_node'):
        proc = _run([lib / exe, '--ros-args', '-p', 'problem:=no_such_problem'], env=env)
        assert proc.returncode == 2 and "unknown problem 'no_such_problem'" in proc.stderr, (
            f'{exe}: exit {proc.returncode}\n{proc.stderr[-2000:]}')


def _copy_package(dest: Path) -> Path:
    """Copy the package's own files (no .venv, build, .git) into dest; return dest."""
    dest.mkdir(parents=True)
    for name in PACKAGE_FILES:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=IGNORED)
        else:
            shutil.copy2(src, dest / name)
    return dest


def _own_installs() -> list[str]:
    """What this interpreter's site-packages holds of sapga_ros (dist-info, editable hooks)."""
    site = Path(sysconfig.get_paths()['purelib'])
    return sorted(p.name for p in site.iterdir() if 'sapga_ros' in p.name)


def _site_packages(prefix: Path) -> Path:
    """The directory under prefix holding the installed sapga_ros package."""
    found = sorted(p.parent for p in prefix.glob(f'lib*/python*/*-packages/{PACKAGE}'))
    assert found, f'no {PACKAGE} package installed under {prefix}'
    return found[0]


def _hook_env(pkg_prefix: Path) -> dict[str, str]:
    """The environment colcon's setup scripts give this package, read from its .dsv hooks."""
    env = _env()

    def apply(dsv: Path) -> None:
        for line in dsv.read_text(encoding='utf-8').splitlines():
            kind, _, rest = line.partition(';')
            if kind == 'source' and rest.endswith('.dsv'):
                apply(pkg_prefix / rest)  # relative to the prefix, or absolute
            elif kind in ('prepend-non-duplicate', 'prepend-non-duplicate-if-exists'):
                name, _, values = rest.partition(';')
                for value in values.split(';'):
                    path = pkg_prefix / value if value else pkg_prefix
                    if kind.endswith('-if-exists') and not path.exists():
                        continue
                    parts = [p for p in env.get(name, '').split(os.pathsep)
                             if p and p != str(path)]
                    env[name] = os.pathsep.join([str(path), *parts])

    apply(pkg_prefix / 'share' / PACKAGE / 'package.dsv')
    return env


@pytest.fixture(scope='module')
def venv_prefix() -> Path:
    """The ament prefix of sapga_ros as `ros2 run` sees it from the project venv."""
    from ament_index_python.packages import get_package_prefix

    saved = os.environ.get('AMENT_PREFIX_PATH')
    paths = [p for p in (saved or '').split(os.pathsep) if p]
    if sys.prefix not in paths:  # make sets it to the venv; a bare pytest run may not
        os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([sys.prefix, *paths])
    try:
        return Path(get_package_prefix(PACKAGE))
    finally:
        if saved is None:
            os.environ.pop('AMENT_PREFIX_PATH', None)
        else:
            os.environ['AMENT_PREFIX_PATH'] = saved


def test_venv_install_has_every_executable_where_ros2_run_looks(venv_prefix):
    """Every executable is an executable file at <ament prefix>/lib/sapga_ros/<exe> in the venv."""
    missing = [exe for exe in EXECUTABLES
               if not _is_executable_file(venv_prefix / 'lib' / PACKAGE / exe)]
    assert not missing, (f'not executable files in {venv_prefix}/lib/{PACKAGE}: {missing} '
                         '(reinstall with `make venv`)')


def test_venv_install_has_package_share_and_every_config(venv_prefix):
    """The venv install carries package.xml and every msg_configs file under share/sapga_ros."""
    share = venv_prefix / 'share' / PACKAGE
    assert (share / 'package.xml').is_file()
    missing = [str(rel) for rel in _config_files()
               if not (share / 'msg_configs' / rel).is_file()]
    assert not missing, f'not installed in {share}/msg_configs: {missing} (run `make venv`)'
    _assert_params_installed(share)


def test_venv_sapga_help_runs_through_ros2_run_path(venv_prefix):
    """`<prefix>/lib/sapga_ros/sapga --help` exits 0, as `ros2 run sapga_ros sapga --help` does."""
    proc = _run([venv_prefix / 'lib' / PACKAGE / 'sapga', '--help'], env=_env())
    _assert_ok(proc, 'sapga --help')
    assert proc.stdout.strip(), 'sapga --help printed nothing'


def test_pip_install_puts_launchers_and_share_files_into_prefix(tmp_path):
    """A plain `pip install` into a prefix gives lib/sapga_ros launchers and the share files."""
    src = _copy_package(tmp_path / 'src')
    prefix = tmp_path / 'prefix'
    venv_installs = _own_installs()
    # without --ignore-installed, pip uninstalls the venv's own sapga_ros to install elsewhere
    proc = _run([sys.executable, '-m', 'pip', 'install', '--quiet', '--disable-pip-version-check',
                 '--no-deps', '--no-build-isolation', '--no-index', '--no-cache-dir',
                 '--ignore-installed', '--no-warn-script-location', '--prefix', prefix, src],
                env=_env())
    _assert_ok(proc, 'pip install')
    assert _own_installs() == venv_installs, 'pip install --prefix changed the venv install'

    for exe in EXECUTABLES:
        assert _is_executable_file(prefix / 'lib' / PACKAGE / exe), f'lib/{PACKAGE}/{exe}'
        assert _is_executable_file(prefix / 'bin' / exe), f'bin/{exe}'
    assert (prefix / 'share/ament_index/resource_index/packages' / PACKAGE).is_file()
    assert (prefix / 'share' / PACKAGE / 'package.xml').is_file()
    assert (prefix / 'share' / PACKAGE / 'msg_configs' / 'acrobot.yaml').is_file()
    for rel in _config_files():
        assert (prefix / 'share' / PACKAGE / 'msg_configs' / rel).is_file(), str(rel)
    _assert_params_installed(prefix / 'share' / PACKAGE)
    for launch_file in sorted((REPO / 'launch').glob('*.launch.py')):   # for ros2 launch
        assert (prefix / 'share' / PACKAGE / 'launch' / launch_file.name).is_file()

    # the launcher runs this prefix's console script, which imports this prefix's package
    env = _env(PYTHONPATH=str(_site_packages(prefix)), AMENT_PREFIX_PATH=str(prefix))
    proc = _run([prefix / 'lib' / PACKAGE / 'sapga', '--help'], env=env)
    _assert_ok(proc, 'pip-installed lib/sapga_ros/sapga --help')
    proc = _run([prefix / 'lib' / PACKAGE / 'sapga', '--version'], env=env)
    _assert_ok(proc, 'pip-installed sapga --version')
    assert proc.stdout.split() == ['sapga', _package_xml_version()]   # from the distribution
    _assert_simulators_start(prefix / 'lib' / PACKAGE, env)


@pytest.mark.parametrize('mode', ['install', 'symlink-install'])
def test_colcon_build_puts_console_scripts_where_ros2_run_looks(tmp_path, mode):
    """`colcon build` installs every executable as a console script in lib/sapga_ros that runs."""
    workspace = tmp_path / 'ws'
    _copy_package(workspace / 'src' / PACKAGE)
    cmd = [sys.executable, '-c', 'import sys; from colcon_core.command import main; '
           'sys.exit(main())',
           '--log-base', workspace / 'log', 'build', '--base-paths', workspace / 'src',
           '--build-base', workspace / 'build', '--install-base', workspace / 'install',
           '--event-handlers', 'console_direct-']
    if mode == 'symlink-install':
        cmd.append('--symlink-install')
    proc = _run(cmd, cwd=workspace, env=_env(COLCON_HOME=str(tmp_path / 'colcon_home')))
    _assert_ok(proc, f'colcon build ({mode})')

    pkg_prefix = workspace / 'install' / PACKAGE
    for exe in EXECUTABLES:
        path = pkg_prefix / 'lib' / PACKAGE / exe
        assert _is_executable_file(path), f'lib/{PACKAGE}/{exe}'
        # a console script, not a wheel launcher pointing at a bin/ colcon does not create
        assert path.read_text(encoding='utf-8').startswith('#!'), path
        assert '../../bin/' not in path.read_text(encoding='utf-8'), f'{path} is a launcher'
    assert (pkg_prefix / 'share/ament_index/resource_index/packages' / PACKAGE).exists()
    for rel in _config_files():
        assert (pkg_prefix / 'share' / PACKAGE / 'msg_configs' / rel).exists(), str(rel)
    _assert_params_installed(pkg_prefix / 'share' / PACKAGE)

    proc = _run([pkg_prefix / 'lib' / PACKAGE / 'sapga', '--help'], env=_hook_env(pkg_prefix))
    _assert_ok(proc, f'colcon-built ({mode}) lib/sapga_ros/sapga --help')
    _assert_simulators_start(pkg_prefix / 'lib' / PACKAGE, _hook_env(pkg_prefix))
