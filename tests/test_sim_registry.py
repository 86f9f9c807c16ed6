"""One problem registry: every model module of sim_nodes/models is registered, dispatched and
simulated, and the simulator of every problem starts and steps exactly like the kernels,
in process and as the installed executables (``sim_node`` and ``<model>_sim``)."""
from __future__ import annotations

import importlib
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from std_msgs.msg import Float64

from ros_helpers import Probe, executable, isolated_ros
from sim_nodes.models import MODELS, model_id
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.models.registry import FOLDER, GENERIC_SIM, model_names, sim_executable
from sim_nodes.problem import Problem, load_problem, problem_names
from sim_nodes.ros.common import JointStateLayout, stamp_ns
from sim_nodes.ros.sim_node import SimNode, mains

STEPS = 6                                 # MDP steps each simulator is driven through
INTERFACE = ('PARAMS', 'pack_params', 'mdp_step', 'mdp_step_lanes')
PROBLEMS = problem_names()
PARAMS_DIR = Path(__file__).resolve().parents[1] / 'msg_configs' / 'params'


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


def test_every_model_module_is_registered_with_the_kernel_interface():
    """MODELS is every module of sim_nodes/models defining mdp_step_lanes, each with the
    whole kernel interface, a problem of its own name (the ``<model>_sim`` default) and a
    simulator executable; every problem's model is one of them."""
    assert MODELS == model_names() and len(MODELS) >= 3
    for name in MODELS:
        module = importlib.import_module(f'sim_nodes.models.{name}')
        missing = [attr for attr in INTERFACE if not hasattr(module, attr)]
        assert not missing, f'{FOLDER / name}.py: model without {missing}'
        assert name in PROBLEMS, f'model {name}: no msg_configs/{name}.yaml'
        assert callable(getattr(mains, sim_executable(name)))
    assert {load_problem(p).model for p in PROBLEMS} <= set(MODELS)


@pytest.mark.parametrize('name', PROBLEMS)
def test_step_lanes_dispatches_every_problem_to_its_model(name, rng):
    """step_lanes with the model's number equals the model's own mdp_step_lanes (==)."""
    problem = load_problem(name)
    width = 16
    states = rng.uniform(problem.low, problem.high, (width, problem.dim)).T.copy()
    actions = rng.choice(problem.action_values, width)
    got, want = states.copy(), states.copy()
    got_r, want_r = np.zeros(width), np.zeros(width)
    step_lanes(model_id(problem.model), got, actions, problem.params(), width, got_r)
    module = importlib.import_module(f'sim_nodes.models.{problem.model}')
    module.mdp_step_lanes(want, actions, problem.params(), width, want_r)
    assert np.array_equal(got, want) and np.array_equal(got_r, want_r)


def test_step_lanes_of_an_unknown_model_number_gives_nan_rewards():
    reward = np.zeros(3)
    step_lanes(len(MODELS), np.zeros((2, 3)), np.zeros(3), np.zeros(7), 2, reward)
    assert np.isnan(reward[:2]).all() and reward[2] == 0.0


def kernel_step(problem: Problem, s: np.ndarray, action: float) -> tuple[np.ndarray, float]:
    """One MDP step of the compiled dispatch the evaluator uses: (new state, reward)."""
    lanes, reward = s.reshape(-1, 1).copy(), np.zeros(1)
    step_lanes(model_id(problem.model), lanes, np.full(1, action), problem.params(), 1, reward)
    return lanes[:, 0], reward[0]


def drive_lockstep(ros, problem: Problem, probe: Probe) -> None:
    """Answer the running lockstep simulator's states with commands; each new state, its
    stamp, effort and reward are the kernel's, bit for bit."""
    ros.wait_for(lambda: probe.command_pub.get_subscription_count() and probe.states,
                 f'the {problem.name} simulator')
    layout = JointStateLayout(problem)
    tick_ns = round(problem.dt * problem.substeps * 1e9)
    s = problem.initial_state
    assert np.array_equal(layout.from_msg(probe.latest_state()), s)
    for k in range(STEPS):
        action = problem.actions[k % len(problem.actions)]
        probe.command_pub.publish(Float64(data=action))
        ros.wait_for(lambda k=k: len(probe.states) > k + 1 and len(probe.rewards) > k,
                     f'state {k + 1} of {problem.name}')
        s, reward = kernel_step(problem, s, action)
        msg = probe.latest_state()
        assert stamp_ns(msg) == (k + 1) * tick_ns
        assert np.array_equal(layout.from_msg(msg), s), f'{problem.name} step {k + 1}'
        assert msg.effort[layout.actuator] == action
        assert probe.rewards[k] == reward


@pytest.mark.parametrize('name', PROBLEMS)
def test_the_simulator_node_of_every_problem_steps_like_its_kernel(ros, name):
    """SimNode in process, lockstep, for each problem in msg_configs."""
    problem = load_problem(name)
    probe = ros.start(Probe, problem=problem)
    sim = ros.start(SimNode, params={'problem': name, 'mode': 'lockstep',
                                     'republish_period': 0.05})
    drive_lockstep(ros, problem, probe)
    assert sim.total_steps == STEPS


@pytest.mark.parametrize('exe,name', [(exe, name) for name in PROBLEMS for exe in
                                      (GENERIC_SIM, sim_executable(load_problem(name).model))])
def test_every_simulator_executable_runs_its_problems_from_the_ros2_run_location(ros, exe, name):
    """``sim_node`` serves every problem, ``<model>_sim`` the problems of its model: started
    from lib/sapga_ros with ``-p problem:=`` they step like the kernel and stop on Ctrl-C."""
    path = executable(exe)
    assert path.parent.parts[-2:] == ('lib', 'sapga_ros') and os.access(path, os.X_OK), path
    problem = load_problem(name)
    probe = ros.start(Probe, problem=problem)
    proc = ros.spawn(exe, '--ros-args', '-p', f'problem:={name}', '-p', 'mode:=lockstep',
                     '-p', 'republish_period:=0.05')
    drive_lockstep(ros, problem, probe)
    # the node's name reaches the graph on its own discovery topic, perhaps after its data
    ros.wait_for(lambda: exe in probe.get_node_names(), f'{exe} on the graph')
    assert ros.stop(proc) == 0


@pytest.mark.parametrize('path', sorted(PARAMS_DIR.glob('*_sim.yaml')), ids=lambda p: p.stem)
def test_simulator_parameter_files_suit_their_executables(ros, path):
    """msg_configs/params/<model>_sim.yaml names a problem of that model and is accepted."""
    params = yaml.safe_load(path.read_text(encoding='utf-8'))['/**']['ros__parameters']
    assert path.stem == sim_executable(load_problem(params['problem']).model)
    sim = ros.start(SimNode, params=params)
    assert sim.problem.name == params['problem'] and sim.settings.mode == params['mode']
