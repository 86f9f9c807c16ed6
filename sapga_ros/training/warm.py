"""Compile every kernel into numba's disk cache: ``python -m sapga_ros.training.warm``.

``make venv`` runs it after installing, so the first ``sapga`` command of a new checkout
loads compiled code instead of compiling in silence (``sim_nodes.jit`` says why a checkout
compiles once).  A few tiny runs call every kernel with the argument types real runs use:
each problem's batch and traced episodes in every exemplar style (and the state-action
batches that predict their lanes or hand over to a catch), a short SAP-GA and
Q-learning training run, the model step the ROS simulator takes (also on a disturbed
plant, ``sim_nodes.disturbance.Plant``), a re-planned episode (``--replan``) and a small
physical-limit search.  On a warm
cache it only loads the cached code.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from sapga_ros.analysis.limit import beam_limit
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.replan import planned_episodes
from sapga_ros.evaluation.replan_settings import ReplanSettings
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.errors import SapgaError
from sapga_ros.policies.classical import ahead, with_catch
from sapga_ros.policies.styles import STYLES
from sapga_ros.optim.operators import random_policy
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train
from sim_nodes.disturbance import Plant, load_disturbance
from sim_nodes.goal import goal_arrays, goal_delta
from sim_nodes.jit import compile_seconds
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem, problem_names

SAPGA = SapgaParams(n_pop=4, n_child=2, l_min=3, l_max=6)


def catch_design(problem):
    """An LQR catch for ``problem`` (region x'Px <= 1), None where it has none."""
    try:
        return classical_policy(problem, c=1.0)
    except SapgaError:
        return None


def warm(problems: list[str] | None = None) -> float:
    """Call every kernel on each of ``problems`` (default: all); seconds spent compiling."""
    names = problems or problem_names()
    for name in names:
        problem = load_problem(name)
        rng = np.random.default_rng(0)
        state = problem.initial_state
        for style in STYLES:
            policies = [random_policy(problem, rng, 3, 6, style) for _ in range(2)]
            evaluator = Evaluator(problem)
            evaluator.evaluate(policies)
            evaluator.episode(policies[0])
            StateSelector(policies[0]).select(state)            # the policy node's call
            if style == 'state-action':     # the batch that predicts its lanes (delay)
                evaluator.evaluate([ahead(p, 1) for p in policies])
                evaluator.episode(ahead(policies[0], 1))
                design = catch_design(problem)  # hybrids: their catches asked lane by lane
                if design is not None:
                    evaluator.evaluate([with_catch(p, design) for p in policies])
                    evaluator.episode(with_catch(policies[0], design))
        # the simulator node's calls
        model_module(problem.model).mdp_step(state, float(problem.actions[0]), problem.params())
        goal_delta(state, *goal_arrays(problem), problem.is_angle)
        for profile in ('field', 'push'):       # every draw the simulator's plant makes
            plant = Plant(problem, load_disturbance(profile))
            s = plant.reset((0, 0, 0, 0))
            plant.observe(s)
            plant.command(float(problem.actions[0]))
            plant.push(s)
        if problem.ends_in_goal:                # decision-time planning (sapga eval --replan)
            planned_episodes(policies[0], problem.default_delta, 'field', 1, 0,
                             ReplanSettings(replan_rounds=1, replan_fit=0.05), 1, 6)
        base = TrainConfig(problem=name, steps=2_000, jobs=1, params=SAPGA)
        train(base)
        train(replace(base, method='ql', steps=1_000, ql=QlParams(chunk_steps=1_000)))
    beam_limit(load_problem(names[0]), n_step=2, width=4, cells=2, per_cell=1)
    return compile_seconds()


def main() -> int:
    start = time.perf_counter()
    compiled = warm(sys.argv[1:] or None)
    print(f'kernels ready in numba\'s cache ({time.perf_counter() - start:.0f} s, '
          f'{compiled:.0f} s of it compiling)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
