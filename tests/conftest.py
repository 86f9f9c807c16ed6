"""Fixtures shared by the test modules: the configured problems and seeded generators.

Keep this file generic.  A module that needs something of its own defines it there (a
fixture of the same name in a module overrides the one here).
"""
from __future__ import annotations

from typing import Iterator

import numpy as np
import pytest

from domains import ros_domain
from sim_nodes.problem import Problem, load_problem

SEED = 20240521  # every random draw of the suite starts here: a failure reproduces


@pytest.fixture(scope='session', autouse=True)
def own_ros_domain() -> Iterator[int]:
    """A ROS domain of this test process (each pytest-xdist worker has its own) and
    localhost-only discovery, for anything that starts ROS without claiming a domain of its
    own: parallel workers never hear each other's nodes."""
    with ros_domain() as domain, pytest.MonkeyPatch.context() as patch:
        patch.setenv('ROS_DOMAIN_ID', str(domain))
        patch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        yield domain


@pytest.fixture
def ros_context(monkeypatch):
    """An rclpy context of its own claimed domain (localhost discovery), shut down after."""
    import rclpy
    from rclpy.context import Context
    with ros_domain() as domain:
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
        ctx = Context()
        rclpy.init(context=ctx, domain_id=domain)
        yield ctx
        rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope='session')
def acrobot_problem() -> Problem:
    """The acrobot of msg_configs/acrobot.yaml (SPEC 2.1)."""
    return load_problem('acrobot')


@pytest.fixture(scope='session')
def pdip_problem() -> Problem:
    """The PDIP of msg_configs/pdip.yaml (SPEC 2.2), l2 = 0.5."""
    return load_problem('pdip')


@pytest.fixture(scope='session')
def pdip_single_problem() -> Problem:
    """The PDIP with l2 = l1 (msg_configs/pdip_single.yaml): the single pendulum."""
    return load_problem('pdip_single')


@pytest.fixture(scope='session', params=['acrobot', 'pdip'])
def problem(request) -> Problem:
    """Each of the paper's two problems in turn."""
    return load_problem(request.param)


@pytest.fixture(scope='session')
def seed() -> int:
    """The suite's seed, for fixtures wider than a test that make their own generator."""
    return SEED


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    """A generator seeded with the suite's seed, fresh for each test."""
    return np.random.default_rng(seed)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption('--long', action='store_true',
                     help='also run the tests marked long (minutes each; `make test-long` '
                          'runs them alone; a smaller form of each runs by default)')


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line('markers', 'long: takes minutes; skipped unless pytest --long '
                                       '(make test-long)')


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption('--long'):
        return
    skip = pytest.mark.skip(reason='long: run with pytest --long (make test-long)')
    for item in items:
        if 'long' in item.keywords:
            item.add_marker(skip)
