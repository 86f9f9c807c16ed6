"""Every executable is where ``ros2 run sapga_ros <exe>`` looks and takes --ros-args."""
import os
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix

from ros_helpers import executable, isolated_ros
from sim_nodes.models import MODELS
from sim_nodes.models.registry import sim_executable

NODES = {
    **{sim_executable(model): [] for model in MODELS},   # its own problem by default
    'acrobot_sim': ['-p', 'mode:=lockstep'],
    'pdip_sim': ['-p', 'problem:=pdip_single'],
    'sim_node': ['-p', 'problem:=mountain_car'],
    'policy_node': ['-p', 'problem:=pdip'],
    'trainer_node': ['-p', 'train_on_start:=false'],
    'recorder_node': [],
}


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def ros2_run_path(exe: str) -> Path:
    """``<ament prefix of sapga_ros>/lib/sapga_ros/<exe>``, as ``ros2 run`` resolves it."""
    return Path(get_package_prefix('sapga_ros')) / 'lib' / 'sapga_ros' / exe


@pytest.mark.parametrize('exe', sorted(NODES))
def test_node_runs_from_the_ros2_run_location_with_ros_args(ros, exe, tmp_path):
    """The node starts from lib/sapga_ros, honours a namespace and node-name remap and
    its -p parameters, and exits 0 on Ctrl-C."""
    path = ros2_run_path(exe)
    assert path.is_file() and os.access(path, os.X_OK), path
    assert executable(exe) == path  # what ros.spawn runs
    args = ['--ros-args', '-r', '__ns:=/exe_test', '-r', f'__node:=renamed_{exe}',
            *NODES[exe]]
    if exe == 'recorder_node':
        args += ['-p', f'output_dir:={tmp_path}']
    proc = ros.spawn(exe, *args)
    probe = ros.start(lambda **kw: __import__('rclpy').create_node('probe', **kw))
    ros.wait_for(lambda: ('renamed_' + exe, '/exe_test') in
                 probe.get_node_names_and_namespaces(), f'{exe} on the graph')
    assert proc.poll() is None
    assert ros.stop(proc) == 0
