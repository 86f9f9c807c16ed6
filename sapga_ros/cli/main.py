"""The ``sapga`` command: train, evaluate, benchmark, inspect exemplars and recordings.

    sapga train --problem P [--method sapga|ql] [--delta D] [--steps N] [--seed S]
                [--jobs J] [--out FILE] [--checkpoint DIR] [--resume] [--init FILE ...]
    sapga eval POLICY [--delta D] [--max-steps N] [--json]
    sapga exemplars POLICY [--json] [--plot OUT.png] [--prune-unused OUT.json]
    sapga bench [--json] [--ros [--problem P]]
    sapga inspect BAG [--json] [--plot OUT.png] [--episode N]
    sapga bag reindex BAG
    sapga experiment [table2] --out DIR [--only 2,4] [--seeds N] [--scale F]
    sapga launch NAME ...

User errors (bad files, unknown problems, invalid numbers) print one line naming what is
wrong and exit with status 2; no traceback.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from pathlib import Path

from sapga_ros.cli.recordings import (add_bag_arguments, add_inspect_arguments, cmd_bag,
                                      cmd_inspect)
from sapga_ros.errors import SapgaError
from sapga_ros.exemplars.styles import STYLES

EXIT_USAGE = 2


def _int_at_least(minimum: int, what: str, maximum: int = 10 ** 15):
    """An argparse type: an integer in [minimum, maximum] (1e6-style numbers allowed)."""
    def parse(text: str) -> int:
        try:
            value = int(float(text)) if 'e' in text.lower() else int(text)
        except (ValueError, OverflowError):
            value = minimum - 1
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f'expected {what}, got {text!r}')
        return value
    return parse


_positive_int = _int_at_least(1, 'a positive integer')
_nonneg_int = _int_at_least(0, 'an integer >= 0')
_episode_steps = _int_at_least(1, 'an integer in [1, 1000000]', 1_000_000)


def _delta(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}')
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'expected a finite delta >= 0, got {text!r}')
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='sapga', description='Exemplar-based policy search (SAP-GA) for pendulums.')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    t = sub.add_parser('train', help='evolve a policy (or run the Q-learning baseline)')
    t.add_argument('--problem', required=True, help='problem name (msg_configs/<name>.yaml)')
    t.add_argument('--method', choices=('sapga', 'ql'), default='sapga',
                   help='SAP-GA (default) or tabular Q-learning')
    t.add_argument('--delta', type=_delta, help='goal difficulty (default: the problem\'s)')
    t.add_argument('--steps', type=_positive_int, default=30_000_000,
                   help='budget of MDP steps simulated (default 30000000)')
    t.add_argument('--seed', type=_nonneg_int, default=0, help='random seed (default 0)')
    t.add_argument('--jobs', type=_nonneg_int, default=0,
                   help='evaluation threads (default 0: every core)')
    t.add_argument('--out', help='policy file to write (default runs/<problem>-<method>-'
                                 'seed<seed>.json); the log goes beside it as .log.csv')
    t.add_argument('--checkpoint', metavar='DIR', help='write checkpoints into DIR')
    t.add_argument('--resume', action='store_true', help='continue from DIR\'s checkpoint')
    t.add_argument('--init', action='append', default=[], metavar='FILE',
                   help='policy file of hand-written exemplars to seed the population '
                        '(repeatable; SAP-GA only)')
    t.add_argument('--style', choices=tuple(STYLES), default='state-action',
                   help='exemplar style of a SAP-GA run (default state-action): '
                        + '; '.join(f'{s.name}: {s.summary}' for s in STYLES.values()))
    t.add_argument('--pop', type=_positive_int, default=100, help='N_pop (default 100)')
    t.add_argument('--children', type=_positive_int, default=10, help='N_child (default 10)')
    t.add_argument('--l-min', type=_positive_int, default=50, help='L_min (default 50)')
    t.add_argument('--l-max', type=_positive_int, default=100, help='L_max (default 100)')
    t.add_argument('--quiet', action='store_true', help='no progress display')

    e = sub.add_parser('eval', help='run a policy\'s episode from the initial state')
    e.add_argument('policy', help='policy file (sapga-policy/1 or sapga-qtable/1)')
    e.add_argument('--delta', type=_delta, help='goal difficulty (default: the policy\'s '
                                                'training delta, else the problem\'s)')
    e.add_argument('--max-steps', type=_episode_steps, help='N_step (default: the problem\'s)')
    e.add_argument('--json', action='store_true', help='print one JSON object')

    x = sub.add_parser('exemplars', help='list, plot or prune a policy\'s exemplars')
    x.add_argument('policy')
    x.add_argument('--delta', type=_delta)
    x.add_argument('--json', action='store_true', help='print the list as JSON')
    x.add_argument('--plot', metavar='OUT.png', help='draw exemplars and the trajectory')
    x.add_argument('--prune-unused', metavar='OUT.json',
                   help='write a copy without the exemplars its episode never refers to')

    b = sub.add_parser('bench', help='batch evaluation speed vs a plain NumPy loop')
    b.add_argument('--json', action='store_true', help='print one JSON object')
    b.add_argument('--ros', action='store_true',
                   help='instead: the lockstep loop through DDS and the policy node\'s '
                        'selection time (sapga_ros.bench.ros)')
    b.add_argument('--problem', default='acrobot', help='with --ros: the problem')
    b.add_argument('--style', choices=(*STYLES, 'all'),
                   help='batch evaluation speed of this exemplar style (or all)')

    add_inspect_arguments(sub.add_parser(
        'inspect', help='summarise (and plot) a recording: a bag directory or an MCAP file'))
    add_bag_arguments(sub.add_parser('bag', help='recording maintenance: bag reindex BAG'))

    ex = sub.add_parser('experiment', help='run the paper\'s experiments (Table 2)')
    ex.add_argument('name', nargs='?', default='table2',
                    help='msg_configs/experiments/<name>.yaml (default table2)')
    ex.add_argument('--out', required=True, help='directory for summary.json and figures')
    ex.add_argument('--only', help='comma-separated experiment ids, e.g. 2,4')
    ex.add_argument('--seeds', type=_positive_int, help='seeds per experiment (default 20)')
    ex.add_argument('--scale', type=_delta, default=1.0,
                    help='multiply every step budget (e.g. 0.1 for a quick look)')
    ex.add_argument('--workers', type=_nonneg_int, default=0,
                    help='parallel runs (default 0: every core)')

    la = sub.add_parser('launch', help='start a group of nodes (swingup, train_deploy)',
                        add_help=False)
    la.add_argument('name', nargs='?', help='swingup or train_deploy')
    la.add_argument('args', nargs=argparse.REMAINDER)
    return parser


def check_output_file(path: Path, option: str) -> None:
    """Refuse, before any work is done, an output path that cannot be written."""
    if path.is_dir():
        raise SapgaError(f'{option} {path}: is a directory')
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SapgaError(f'{option} {path}: cannot create its folder ({exc.strerror})') from exc
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise SapgaError(f'{option} {path}: not writable')


def _default_out(args) -> Path:
    return Path('runs') / f'{args.problem}-{args.method}-seed{args.seed}.json'


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


def cmd_train(args) -> int:
    from sapga_ros.training.loop import write_log
    from sapga_ros.exemplars.policy import load_policy
    from sapga_ros.training.ql_run import train_ql
    from sapga_ros.optim.sapga import SapgaParams
    from sapga_ros.training.loop import TrainConfig, train_sapga
    from sim_nodes.problem import load_problem

    problem = load_problem(args.problem)
    if args.l_min > args.l_max:
        raise SapgaError(f'--l-min {args.l_min} is larger than --l-max {args.l_max}')
    if args.pop < 2:
        raise SapgaError('--pop must be at least 2')
    initial = [load_policy(f, problem) for f in args.init]
    if initial and args.method != 'sapga':
        raise SapgaError('--init seeds a SAP-GA population; Q-learning takes none')
    for f, policy in zip(args.init, initial):
        if policy.style != args.style:
            raise SapgaError(f'{f}: a {policy.style} policy cannot seed a {args.style} run '
                             f'(--style {policy.style})')
    config = TrainConfig(problem=problem.name, method=args.method, delta=args.delta,
                         steps=args.steps, seed=args.seed, jobs=args.jobs,
                         checkpoint=args.checkpoint, resume=args.resume,
                         params=SapgaParams(n_pop=args.pop, n_child=args.children,
                                            l_min=args.l_min, l_max=args.l_max,
                                            style=args.style))
    out = Path(args.out) if args.out else _default_out(args)
    check_output_file(out, '--out')
    if args.checkpoint and Path(args.checkpoint).exists() and not Path(args.checkpoint).is_dir():
        raise SapgaError(f'--checkpoint {args.checkpoint}: exists and is not a directory')
    progress = _Progress(args.steps, args.quiet)
    interrupted = []

    def on_sigint(signum, frame):  # finish the generation, then save what was found
        if interrupted:
            raise KeyboardInterrupt
        interrupted.append(signum)
        print('\nsapga train: interrupted; saving the best so far (Ctrl-C again to abandon)',
              file=sys.stderr)

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        if args.method == 'sapga':
            result = train_sapga(config, initial, progress, should_stop=lambda: bool(interrupted))
        else:
            result = train_ql(config, progress, should_stop=lambda: bool(interrupted))
    finally:
        signal.signal(signal.SIGINT, previous)
        progress.close()
    result.policy.save(out)
    log = out.with_suffix('.log.csv')
    write_log(log, result.history)
    meta = result.policy.meta
    print(f"{problem.name} {args.method}: best value {meta['value']:.3f}, policy delta* "
          f"{meta['delta_star']:.4f}, run delta* {meta['run_delta_star']:.4f} "
          f"({'achieved' if meta['run_delta_star'] <= meta['delta'] else 'not achieved'} "
          f"delta {meta['delta']}), {meta['steps']:,d} steps")
    print(f'policy: {out}\nlog: {log}')
    return 130 if interrupted else 0


def _eval_delta(args, policy) -> float:
    if args.delta is not None:
        return args.delta
    meta_delta = policy.meta.get('delta') if isinstance(policy.meta, dict) else None
    if isinstance(meta_delta, (int, float)) and math.isfinite(meta_delta) and meta_delta >= 0:
        return float(meta_delta)
    return policy.problem.default_delta


def cmd_eval(args) -> int:
    from sapga_ros.evaluation.any_policy import load_any_policy, run_policy_episode
    policy = load_any_policy(args.policy)
    delta = _eval_delta(args, policy)
    ep = run_policy_episode(policy, delta, args.max_steps)
    if args.json:
        print(json.dumps(ep.summary()))
    else:
        reached = 'reached' if ep.reached else 'did not reach'
        print(f'{policy.problem.name}: return {ep.ret:.6f}, delta* {ep.delta_star:.6f}, '
              f'steps {ep.steps}, {reached} S_delta (delta {delta})')
    return 0


def cmd_exemplars(args) -> int:
    from sapga_ros.evaluation.any_policy import run_policy_episode
    import numpy as np

    from sapga_ros.exemplars.tools import exemplar_table, format_table
    from sapga_ros.exemplars.policy import load_policy
    policy = load_policy(args.policy)
    delta = _eval_delta(args, policy)
    ep = run_policy_episode(policy, delta)
    reported = ep.exemplars[ep.exemplars >= 0]
    counts = np.bincount(reported, minlength=len(policy))
    rows = exemplar_table(policy, counts, ep.used)
    if args.json:
        print(json.dumps(rows))
    else:
        print(f'{policy.problem.name}, {policy.style} style')
        print('\n'.join(format_table(policy, rows)))
        print(f'{int(ep.used.sum())} of {len(policy)} exemplars referred to in its '
              f'episode of {ep.steps} steps')
    if args.plot:
        from sapga_ros.viz.exemplar_plot import plot_exemplars
        check_output_file(Path(args.plot), '--plot')
        plot_exemplars(policy, ep, counts, args.plot)
        print(f'plot: {args.plot}', file=sys.stderr)
    if args.prune_unused:
        check_output_file(Path(args.prune_unused), '--prune-unused')
        keep = ep.used
        pruned = policy.subset(keep)
        pruned.meta = {**policy.meta, 'pruned_from': str(args.policy)}
        pruned.save(args.prune_unused)
        print(f'pruned policy ({int(keep.sum())} exemplars): {args.prune_unused}',
              file=sys.stderr)
    return 0


def cmd_bench(args) -> int:
    if args.ros:
        from sapga_ros.bench.ros import main as bench_ros
        return bench_ros(['--problem', args.problem, '--processes'])
    if args.style:
        return _bench_styles(args)
    from sapga_ros.bench.batch import run_bench
    result = run_bench()
    if args.json:
        print(json.dumps({k: v for k, v in result.items() if k != 'details'}))
        return 0
    for d in result['details']:
        print(f"{d['problem']:8s} batch: {d['steps_per_s_per_core'] / 1e6:6.3f} M steps/s per "
              f"core, {d['steps_per_s_all_cores'] / 1e6:6.3f} M steps/s on {d['threads']} "
              f"threads; NumPy loop: {d['numpy_steps_per_s']:8.0f} steps/s; speedup per core "
              f"{d['speedup_vs_numpy']:6.0f}x")
    return 0


def _bench_styles(args) -> int:
    from sapga_ros.bench.batch import run_style_bench
    result = run_style_bench(list(STYLES) if args.style == 'all' else [args.style])
    if args.json:
        print(json.dumps(result))
        return 0
    for style, d in result.items():
        print(f"{style:18s} acrobot {d['acrobot_steps_per_s_per_core'] / 1e6:6.3f} M steps/s "
              f"per core ({d['acrobot_steps_per_s_all_cores'] / 1e6:6.3f} M on "
              f"{d['threads']} threads); pdip {d['pdip_steps_per_s_per_core'] / 1e6:6.3f} M "
              f"per core ({d['pdip_steps_per_s_all_cores'] / 1e6:6.3f} M)")
    return 0


def cmd_experiment(args) -> int:
    from sapga_ros.training.experiments import run_experiments
    only = None
    if args.only:
        try:
            only = [int(x) for x in args.only.split(',') if x.strip()]
        except ValueError:
            raise SapgaError(f'--only: expected comma-separated ids, got {args.only!r}')
    run_experiments(args.name, args.out, only, args.seeds, args.scale, args.workers or None)
    return 0


def cmd_launch(args) -> int:
    from sapga_ros.launch import run_launch
    return run_launch(args.name or '--help', args.args)


COMMANDS = {'train': cmd_train, 'eval': cmd_eval, 'exemplars': cmd_exemplars,
            'bench': cmd_bench, 'inspect': cmd_inspect, 'bag': cmd_bag, 'launch': cmd_launch,
            'experiment': cmd_experiment}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except SapgaError as exc:
        print(f'sapga {args.command}: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        return 0
    except OSError as exc:
        where = f'{exc.filename}: ' if exc.filename else ''
        print(f'sapga {args.command}: error: {where}{exc.strerror or exc}', file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print(f'sapga {args.command}: error: out of memory', file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f'sapga {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
