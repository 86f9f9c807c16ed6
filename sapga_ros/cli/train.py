"""``sapga train``: one training run (SAP-GA, the Q-learning baseline or CMA-ES) from the
command line.

Its options are the run's files (``--problem``, ``--out``, ``--checkpoint``, ``--init``,
``--quiet``) and, generated from the config dataclasses (``TrainConfig``, ``SapgaParams``,
``QlParams``, ``CmaesParams``; defaults, help and bounds declared there), the run's settings;
``train_plan.py`` turns them into a run and its files (``--resume``: the checkpoint's
settings).  The best policy so far, the log and the checkpoint are saved at least every
``--checkpoint-seconds`` (30 s), so a killed run loses at most that.  Ctrl-C or SIGTERM
finishes the current round and still writes the best policy, log and checkpoint (exit
status 130 or 143); a second one abandons the round.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time

from sapga_ros.cli.args import add_settings
from sapga_ros.cli.train_plan import plan
from sapga_ros.errors import SapgaError
from sapga_ros.optim.cmaes import CmaesParams
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig
from sim_nodes.params import build

SETTINGS = (TrainConfig, SapgaParams, QlParams, CmaesParams)
SIGNALS = {signal.SIGINT: 'Ctrl-C', signal.SIGTERM: 'SIGTERM'}


def add_train_arguments(t: argparse.ArgumentParser) -> None:
    t.add_argument('--problem', help='problem name (msg_configs/<name>.yaml); required but '
                                     'with --resume, which takes the checkpoint\'s')
    t.add_argument('--out', help='policy file to write, in an existing folder (default runs/'
                                 '<problem>-<method>-seed<seed>.json); the log goes beside it '
                                 'as .log.csv')
    t.add_argument('--checkpoint', metavar='DIR',
                   help='checkpoint directory (default: beside the policy file, <out without '
                        '.json>.ckpt/); --resume continues its run, taking every setting not '
                        'given from it')
    t.add_argument('--init', action='append', default=[], metavar='FILE',
                   help='policy file of hand-written exemplars to seed the population '
                        '(repeatable; SAP-GA only; a file designed for a delay seeds a run of '
                        'that --delay, a hybrid one behind its own catch)')
    t.add_argument('--quiet', action='store_true', help='no progress display')
    for cls in SETTINGS:
        add_settings(t, cls)


def train_config(args: argparse.Namespace, problem: str) -> TrainConfig:
    """The run the parsed options describe, without reading a checkpoint (``plan`` is what
    ``sapga train`` runs)."""
    value = lambda name: getattr(args, name)  # noqa: E731
    return build(TrainConfig, value, problem=problem, checkpoint=args.checkpoint,
                 params=build(SapgaParams, value), ql=build(QlParams, value),
                 cmaes=build(CmaesParams, value))


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
        if 'best_hold_fraction' in row:       # the hold task
            text += (f"  hold {row['best_hold_fraction']:.3f} from step "
                     f"{row['best_first_entry_step']}, rail {row['best_rail_contacts']}")
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
    from sapga_ros.policies.classical import catch_delay, is_classical, selector_delay
    from sapga_ros.policies.runnable import load_policy
    from sapga_ros.training.loop import train, write_log
    from sim_nodes.problem import load_problem

    run = plan(args)
    config = run.config
    problem = load_problem(config.problem)
    initial = [load_policy(f, problem) for f in args.init]
    if initial and config.method != 'sapga':
        raise SapgaError(f'--init seeds a SAP-GA population; {config.method} takes none')
    for f, policy in zip(args.init, initial):
        if policy.style != config.params.style:
            raise SapgaError(f'{f}: a {policy.style} policy cannot seed a '
                             f'{config.params.style} run (--style {policy.style})')
        if is_classical(policy):                # no exemplars, a controller of its own
            raise SapgaError(f'{f}: a classical policy has no exemplars to seed a run')
        delay = selector_delay(policy)
        if delay and delay != config.delay:     # a file's delay is never dropped unsaid
            raise SapgaError(f'{f}: designed for a delay of {delay} MDP step(s); this run: '
                             f'{config.delay} (--delay {delay} to train for it)')
        catch = catch_delay(policy)             # nor a hybrid's catch
        if catch is not None and (config.catch != 'lqr' or catch != config.catch_delay):
            raise SapgaError(f'{f}: a hybrid whose catch is designed for a delay of {catch} '
                             'MDP step(s); this run: ' + (
                                 f'a catch designed for {config.catch_delay}'
                                 if config.catch == 'lqr' else 'no catch') +
                             f' (--catch lqr --catch-delay {catch} to train behind it)')
    progress = _Progress(config.steps, args.quiet)
    received: list[int] = []

    def on_signal(signum: int, frame: object) -> None:  # finish the round, then save
        if received:
            raise KeyboardInterrupt
        received.append(signum)
        print(f'\nsapga train: {SIGNALS[signum]}: saving the best so far after this round '
              '(again to abandon it)', file=sys.stderr, flush=True)

    def on_save(policy: object, history: list[dict]) -> None:
        policy.save(run.out)
        write_log(run.log, history)

    previous = {s: signal.signal(s, on_signal) for s in SIGNALS}
    try:
        result = train(config, initial, progress, should_stop=lambda: bool(received),
                       on_save=on_save)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        progress.close()
    on_save(result.policy, result.history)
    meta = result.policy.meta
    print(f"{problem.name} {config.method}: best value {meta['value']:.3f}, policy delta* "
          f"{meta['delta_star']:.4f}, run delta* {meta['run_delta_star']:.4f} "
          f"({'achieved' if meta['run_delta_star'] <= meta['delta'] else 'not achieved'} "
          f"delta {meta['delta']}), {meta['steps']:,d} steps")
    if not problem.ends_in_goal:
        print(f"hold: first entry step {meta['first_entry_step']}, hold fraction "
              f"{meta['hold_fraction']:.4f}, rail contacts {meta['rail_contacts']}")
    print(f'policy: {run.out}\nlog: {run.log}\ncheckpoint: {run.checkpoint}')
    return 128 + received[0] if received else 0
