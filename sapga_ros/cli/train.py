"""``sapga train``: one training run (SAP-GA or the Q-learning baseline) from the command line.

Its options are the run's files (``--problem``, ``--delta``, ``--out``, ``--checkpoint``,
``--init``, ``--quiet``) and, generated from the config dataclasses (``TrainConfig``,
``SapgaParams``, ``QlParams``; defaults, help and bounds written there), the run's settings.
Ctrl-C finishes the current round and still writes the best policy, log and checkpoint.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from sapga_ros.cli.args import add_settings, check_output_file, delta_value
from sapga_ros.errors import SapgaError
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.optim.settings import build
from sapga_ros.training.loop import TrainConfig

SETTINGS = (TrainConfig, SapgaParams, QlParams)


def add_train_arguments(t: argparse.ArgumentParser) -> None:
    t.add_argument('--problem', required=True, help='problem name (msg_configs/<name>.yaml)')
    t.add_argument('--delta', type=delta_value, help='goal difficulty (default: the problem\'s)')
    t.add_argument('--out', help='policy file to write (default runs/<problem>-<method>-'
                                 'seed<seed>.json); the log goes beside it as .log.csv')
    t.add_argument('--checkpoint', metavar='DIR', help='write checkpoints into DIR')
    t.add_argument('--init', action='append', default=[], metavar='FILE',
                   help='policy file of hand-written exemplars to seed the population '
                        '(repeatable; SAP-GA only)')
    t.add_argument('--quiet', action='store_true', help='no progress display')
    for cls in SETTINGS:
        add_settings(t, cls)


def train_config(args: argparse.Namespace, problem: str) -> TrainConfig:
    """The run the parsed options describe."""
    value = lambda name: getattr(args, name)  # noqa: E731
    return build(TrainConfig, value, problem=problem, delta=args.delta,
                 checkpoint=args.checkpoint, params=build(SapgaParams, value),
                 ql=build(QlParams, value))


class _Progress:
    """tqdm bar on a terminal; a line every few seconds otherwise."""

    def __init__(self, total: int, quiet: bool) -> None:
        self.total = total
        self.quiet = quiet
        self.bar = None
        self.last = 0.0
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=total, unit='step', unit_scale=True, file=sys.stderr)

    def __call__(self, row: dict) -> None:
        text = (f"best {row['best_value']:.2f}  delta* {row['delta_star']:.4f}  "
                f"{row['steps_per_s'] / 1e6:.2f} M steps/s")
        if self.bar is not None:
            self.bar.update(min(row['steps'], self.total) - self.bar.n)
            self.bar.set_postfix_str(text)
        elif not self.quiet and time.monotonic() - self.last > 5.0:
            self.last = time.monotonic()
            print(f"steps {row['steps']:>11,d}  {text}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def cmd_train(args: argparse.Namespace) -> int:
    from sapga_ros.exemplars.policy import load_policy
    from sapga_ros.training.loop import train, write_log
    from sim_nodes.problem import load_problem

    problem = load_problem(args.problem)
    config = train_config(args, problem.name)
    initial = [load_policy(f, problem) for f in args.init]
    if initial and config.method != 'sapga':
        raise SapgaError('--init seeds a SAP-GA population; Q-learning takes none')
    for f, policy in zip(args.init, initial):
        if policy.style != config.params.style:
            raise SapgaError(f'{f}: a {policy.style} policy cannot seed a '
                             f'{config.params.style} run (--style {policy.style})')
    out = Path(args.out) if args.out else \
        Path('runs') / f'{problem.name}-{config.method}-seed{config.seed}.json'
    check_output_file(out, '--out')
    if args.checkpoint and Path(args.checkpoint).exists() and not Path(args.checkpoint).is_dir():
        raise SapgaError(f'--checkpoint {args.checkpoint}: exists and is not a directory')
    progress = _Progress(config.steps, args.quiet)
    interrupted = []

    def on_sigint(signum, frame):  # finish the round, then save what was found
        if interrupted:
            raise KeyboardInterrupt
        interrupted.append(signum)
        print('\nsapga train: interrupted; saving the best so far (Ctrl-C again to abandon)',
              file=sys.stderr)

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        result = train(config, initial, progress, should_stop=lambda: bool(interrupted))
    finally:
        signal.signal(signal.SIGINT, previous)
        progress.close()
    result.policy.save(out)
    log = out.with_suffix('.log.csv')
    write_log(log, result.history)
    meta = result.policy.meta
    print(f"{problem.name} {config.method}: best value {meta['value']:.3f}, policy delta* "
          f"{meta['delta_star']:.4f}, run delta* {meta['run_delta_star']:.4f} "
          f"({'achieved' if meta['run_delta_star'] <= meta['delta'] else 'not achieved'} "
          f"delta {meta['delta']}), {meta['steps']:,d} steps")
    print(f'policy: {out}\nlog: {log}')
    return 130 if interrupted else 0
