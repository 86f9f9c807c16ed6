"""The trainer node's parameters, from the config dataclasses' declarations.

Every parameter of ``TrainConfig``, ``SapgaParams``, ``QlParams``, ``CmaesParams`` and
``NodeSettings`` (``sim_nodes.params``) is a parameter of the same name, default, range and
description;
``delta`` is declared as the problem's ``episode.delta`` unless given.  Written here are only
the node's own three: ``problem`` (read-only), ``managed`` (read-only: wait for lifecycle
transitions) and ``checkpoint`` ('': ``<out without suffix>.ckpt`` beside ``out``; none
without ``out``).  A change applies to the next run.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from sapga_ros.errors import ConfigError
from sapga_ros.optim.cmaes import CmaesParams
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig
from sim_nodes.params import Param, build, declared, param
from sim_nodes.ros.params import check


@dataclass(frozen=True)
class NodeSettings:
    """The trainer node's own parameters (beside the run's)."""

    out: str = param('', 'best policy file to write (its .log.csv beside it); empty: none')
    train_on_start: bool = param(False, 'start a run when the node starts')
    policy_file: str = param('', 'policy served on get_policy until training has a best (one '
                             'that cannot be served at start: one line, exit 2); empty: '
                             'none')
    diagnostics_period: float = param(1.0, 'between /diagnostics messages', low=1e-3,
                                      high=3600.0, unit='s')
    log_period: float = param(5.0, 'between progress lines in the log', low=1e-3,
                              high=3600.0, unit='s')


PROBLEM = Param('problem', 'acrobot', 'msg_configs/<problem>.yaml', read_only=True)
MANAGED = Param('managed', False, 'wait for lifecycle transitions (configure, activate, ...) '
                'instead of serving at once', read_only=True)
CHECKPOINT = Param('checkpoint', '', 'checkpoint directory; empty: <out without suffix>.ckpt '
                   'beside out (none without out)')
SOURCES = (TrainConfig, SapgaParams, QlParams, CmaesParams, NodeSettings)
PARAMETERS = (PROBLEM, MANAGED, *(p for cls in SOURCES for p in declared(cls)), CHECKPOINT)


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None."""
    return check(PARAMETERS, name, value)


def train_config(value: Callable[[str], Any], problem: str) -> TrainConfig:
    """The run parameters ``value(name)`` describe (ConfigError if inconsistent, or if
    ``out`` or the checkpoint directory is not in an existing folder)."""
    out = value('out')
    checkpoint = value('checkpoint') or (str(Path(out).with_suffix('.ckpt')) if out else '')
    if value('resume') and not checkpoint:
        raise ConfigError('resume needs a checkpoint directory (parameter checkpoint, or out: '
                          'the checkpoint beside it)')
    for what, path in (('out', out), ('checkpoint', checkpoint)):
        if path and not Path(path).parent.is_dir():
            raise ConfigError(f'{what} {path}: {Path(path).parent} is not an existing folder')
    return build(TrainConfig, value, problem=problem, checkpoint=checkpoint or None,
                 params=build(SapgaParams, value), ql=build(QlParams, value),
                 cmaes=build(CmaesParams, value))
