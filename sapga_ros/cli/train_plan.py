"""What a ``sapga train`` command line asks for: the run's config and its files.

Files: the policy ``--out`` (default ``runs/<problem>-<method>-seed<seed>.json``, whose
``runs/`` folder is the only one ever created; a given ``--out`` must be in an existing
folder), its log beside it (``.log.csv``) and the checkpoint directory ``--checkpoint``
(default: beside the policy, ``<out without suffix>.ckpt/``; it may be created, its parent
must exist).  Every run checkpoints.

``--resume`` continues the run of the checkpoint: the settings not given on the command
line (problem, method, delta, seed, budget, population, style, ...) are the checkpoint's, so
``sapga train --resume --out p.json`` continues what ``sapga train ... --out p.json``
started; a given run setting that differs from the checkpoint's is refused by the training
loop with one line naming the differences.  The checkpoint is the one of ``--checkpoint``,
else the one beside ``--out``, else the one beside the default ``--out`` of ``--problem``.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

from sapga_ros.cli.args import check_output_dir, check_output_file
from sapga_ros.errors import CheckpointError, ConfigError, SapgaError
from sapga_ros.io.checkpoint import load_checkpoint_meta
from sapga_ros.optim.cmaes import CmaesParams
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.checkpoints import flat
from sapga_ros.training.loop import TrainConfig
from sim_nodes.params import DELTA, build

RUNS = Path('runs')            # the default policy file's folder


@dataclass(frozen=True)
class Plan:
    """A run and where its policy, log and checkpoint go."""

    config: TrainConfig
    out: Path
    log: Path
    checkpoint: Path


def default_out(problem: str, method: str, seed: int) -> Path:
    return RUNS / f'{problem}-{method}-seed{seed}.json'


def checkpoint_beside(out: Path) -> Path:
    """The default checkpoint directory of the policy file ``out``."""
    return out.with_suffix('.ckpt')


def plan(args: argparse.Namespace) -> Plan:
    """The run and files the parsed ``sapga train`` options describe (SapgaError if they
    cannot work); reads the checkpoint's settings with ``--resume``."""
    given = set(getattr(args, 'given', ()))
    value: Callable[[str], Any] = lambda name: getattr(args, name)  # noqa: E731
    problem = args.problem
    checkpoint = Path(args.checkpoint) if args.checkpoint else None
    if args.resume:
        checkpoint = checkpoint or _resumed_checkpoint(args)
        saved = _saved_settings(checkpoint)
        problem = problem or saved.get('problem')
        value = lambda name: (getattr(args, name) if name in given  # noqa: E731
                              or name not in saved else saved[name])
    elif not problem:
        raise SapgaError('--problem is required (only --resume takes it from the checkpoint)')
    try:
        config = build(TrainConfig, value, problem=problem, params=build(SapgaParams, value),
                       ql=build(QlParams, value), cmaes=build(CmaesParams, value))
    except (ConfigError, TypeError) as exc:
        if not args.resume:
            raise
        raise CheckpointError(f'{checkpoint}: with the checkpoint\'s settings: {exc}') from exc
    if args.out:
        out = Path(args.out)
    else:
        out = default_out(config.problem, config.method, config.seed)
        out.parent.mkdir(parents=True, exist_ok=True)
    check_output_file(out, '--out')
    checkpoint = checkpoint or checkpoint_beside(out)
    check_output_dir(checkpoint, '--checkpoint')
    config = replace(config, checkpoint=str(checkpoint))
    return Plan(config, out, out.with_suffix('.log.csv'), checkpoint)


def _resumed_checkpoint(args: argparse.Namespace) -> Path:
    """The checkpoint directory ``--resume`` reads when ``--checkpoint`` is not given."""
    if args.out:
        return checkpoint_beside(Path(args.out))
    if args.problem:
        return checkpoint_beside(default_out(args.problem, args.method, args.seed))
    raise SapgaError('--resume needs --checkpoint DIR, or --out FILE or --problem to find '
                     'the checkpoint beside the policy file')


def _saved_settings(checkpoint: Path) -> dict[str, Any]:
    """The run settings recorded in the checkpoint: name -> value (``problem``, ``delta``,
    ``method``, ``seed``, the strategy parameters, and the budget and other settings)."""
    meta = load_checkpoint_meta(checkpoint)
    settings = meta.get('settings', {})
    if not isinstance(meta.get('run'), dict) or not isinstance(settings, dict):
        raise CheckpointError(f'{checkpoint}: the checkpoint records no run settings')
    saved = {**flat(meta['run']), **settings}
    if not isinstance(saved.get('problem'), str):
        raise CheckpointError(f'{checkpoint}: the checkpoint names no problem')
    reason = DELTA.reason(saved.get('delta'))
    if reason:
        raise CheckpointError(f'{checkpoint}: the checkpoint\'s {reason}'[:300])
    return saved
