"""Every configured problem as a Gymnasium environment: ``import sapga_ros.gym`` registers them.

    import gymnasium
    import sapga_ros.gym
    env = gymnasium.make('sapga_ros/Acrobot-v0', delta=0.05)

One id per problem of the registry (``sim_nodes.problem.problem_names``), in the
``sapga_ros`` namespace: the four of the paper's comparisons have fixed names
(``Acrobot-v0``, ``PDIP-v0``, ``PDIPSingle-v0``, ``MountainCar-v0``), every other problem
is its name in CamelCase (``pendulum`` -> ``Pendulum-v0``).  ``make`` passes ``delta`` and
``n_step`` on to ``ProblemEnv`` (``sapga_ros.gym.env``, its manual).
"""
from __future__ import annotations

import gymnasium

from sapga_ros.gym.env import ProblemEnv
from sim_nodes.problem import problem_names

NAMESPACE = 'sapga_ros'
FIXED_NAMES = {'acrobot': 'Acrobot', 'pdip': 'PDIP', 'pdip_single': 'PDIPSingle',
               'mountain_car': 'MountainCar'}
ENTRY_POINT = 'sapga_ros.gym.env:ProblemEnv'

__all__ = ['ENV_IDS', 'ProblemEnv', 'env_id', 'register_problems']


def env_id(problem: str) -> str:
    """The Gymnasium id of the problem called ``problem``."""
    name = FIXED_NAMES.get(problem) or ''.join(w.capitalize() for w in problem.split('_'))
    return f'{NAMESPACE}/{name}-v0'


def register_problems() -> dict[str, str]:
    """Register every configured problem not yet registered; problem name -> id."""
    ids = {}
    for problem in problem_names():
        ids[problem] = env_id(problem)
        if ids[problem] not in gymnasium.registry:
            gymnasium.register(ids[problem], entry_point=ENTRY_POINT,
                               kwargs={'problem': problem})
    return ids


ENV_IDS = register_problems()
