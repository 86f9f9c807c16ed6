"""What finite-difference velocities cost a policy: episodes on the kernel where the
selector sees the state the policy node reads from a ``JointState`` without velocities
(``RobotState``, ``velocity_source: difference``) against the true state.

Run as a script for the numbers of any policy files (docs/ros_interface.md quotes them)::

    python tests/test_velocity_estimate.py POLICY.json ... [--episodes N] [--spread X]

Each policy runs N episodes from the initial state spread by U(-X, X) per coordinate (0.01)
(seeded), once with true and once with estimated velocities; a success is entering S_delta
(hold problems: hold_fraction >= 0.9).
"""
from __future__ import annotations

import argparse
import array
import sys
from types import SimpleNamespace

import numpy as np

from sapga_ros.policies.runnable import load_policy
from sapga_ros.nodes.joint_mapping import JointMapping, RobotState
from sapga_ros.nodes.policy_loader import PreparedPolicy
from sim_nodes.goal import goal_arrays, goal_delta, hold_measures
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout

SPREAD = 0.01
HOLD_SUCCESS = 0.9


def positions_only(layout: JointStateLayout, s: np.ndarray, stamp: int) -> SimpleNamespace:
    """A JointState of ``s`` at ``stamp`` [ns] without velocities (as a robot may send)."""
    msg = layout.to_msg(s, 0.0, stamp)
    return SimpleNamespace(name=msg.name, position=msg.position, velocity=array.array('d'),
                           header=msg.header)


def episode(policy, problem, s0: np.ndarray, estimate: bool) -> bool:
    """One episode from ``s0``; True for a success (module docstring)."""
    step = model_module(problem.model).mdp_step
    p = problem.params()
    best, inv_scale, fixed = goal_arrays(problem)
    selector = PreparedPolicy.of(policy, 'study').selector
    selector.reset()
    layout = JointStateLayout(problem)
    robot = RobotState(JointMapping.of(problem, {'velocity_source': 'difference'}))
    tick = round(problem.dt * problem.substeps * 1e9)
    s = s0.copy()
    first = held = 0
    for k in range(problem.n_step + 1):
        seen = s
        if estimate:
            seen = robot.read(positions_only(layout, s, k * tick))
        if k == problem.n_step:
            break
        _, action = selector.select(seen)
        step(s, action, p)
        inside = goal_delta(s, best, inv_scale, fixed, problem.is_angle) <= problem.default_delta
        if inside:
            first, held = first or k + 1, held + 1
            if problem.ends_in_goal:
                return True
    if problem.ends_in_goal:
        return False
    return hold_measures(first, held, problem.n_step, 0)['hold_fraction'] >= HOLD_SUCCESS


def success_rates(path: str, episodes: int, spread: float = SPREAD, seed: int = 0
                  ) -> tuple[float, float]:
    """(rate with true velocities, rate with finite differences) of policy file ``path``."""
    policy = load_policy(path)
    problem = policy.problem
    rng = np.random.default_rng(seed)
    starts = problem.initial_state + rng.uniform(-spread, spread, (episodes, problem.dim))
    true = sum(episode(policy, problem, s0, False) for s0 in starts)
    estimated = sum(episode(policy, problem, s0, True) for s0 in starts)
    return true / episodes, estimated / episodes


def test_estimated_velocities_track_the_true_ones_along_a_swing_up(tmp_path):
    """Along the classical acrobot_hold controller's swing-up and hold (true velocities
    steering), the estimate from positions alone is within 0.1 rad/s on average (measured:
    0.02 and 0.03) and 1 rad/s at worst (measured: 0.2 and 0.4); the velocity ranges are
    8pi and 18pi rad/s."""
    from sapga_ros.cli.main import main as sapga
    path = tmp_path / 'c.json'
    assert sapga(['classical', '--problem', 'acrobot_hold', '--out', str(path)]) == 0
    problem = load_problem('acrobot_hold')
    policy = load_policy(path)
    step = model_module(problem.model).mdp_step
    p = problem.params()
    selector = PreparedPolicy.of(policy, 'study').selector
    robot = RobotState(JointMapping.of(problem, {'velocity_source': 'difference'}))
    s = problem.initial_state.copy()
    errors = []
    for k in range(problem.n_step):
        seen = robot.read(positions_only(JointStateLayout(problem), s, k * 50_000_000))
        errors.append(np.abs(seen[2:] - s[2:]))
        step(s, selector.select(s)[1], p)
    errors = np.array(errors)
    assert np.abs(s[2:]).max() < 1.0 and errors.max(axis=0)[0] > 0   # held, after moving
    assert (errors.mean(axis=0) < 0.1).all() and (errors.max(axis=0) < 1.0).all()


def test_the_estimate_is_exact_on_a_quadratic_path_with_uneven_stamps():
    problem = load_problem('acrobot')
    robot = RobotState(JointMapping.of(problem, {'velocity_source': 'difference'}))
    layout = JointStateLayout(problem)
    for t in (0.0, 0.05, 0.12, 0.15):
        s = np.array([1.0 + 2.0 * t + 3.0 * t * t, -t * t, 0.0, 0.0])
        seen = robot.read(positions_only(layout, s, round(t * 1e9)))
    assert np.allclose(seen[2:], [2.0 + 6.0 * 0.15, -0.3], atol=1e-9)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('policies', nargs='+')
    parser.add_argument('--episodes', type=int, default=50)
    parser.add_argument('--spread', type=float, default=SPREAD)
    args = parser.parse_args(argv)
    print(f'{"policy":40s} {"true velocities":>16s} {"differences":>12s}')
    for path in args.policies:
        true, est = success_rates(path, args.episodes, args.spread)
        print(f'{path[-40:]:40s} {true:16.2f} {est:12.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main(sys.argv[1:]))
