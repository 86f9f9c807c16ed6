"""The ``sapga`` command: train, evaluate, benchmark, inspect exemplars and recordings.

    sapga train --problem P [--method sapga|ql|cmaes] [--delta D] [--steps N] [--seed S]
                [--jobs J] [--out FILE] [--checkpoint DIR] [--resume] [--init FILE ...]
                [--style S] [--pop N] [--children N] [--l-min N] [--l-max N] ...
    sapga eval POLICY [--delta D] [--max-steps N] [--json] [--delay N]
               [--disturbance NAME [--episodes N] [--seed S]]
    sapga robustness POLICY ... --out DIR [--disturbance NAME ...] [--scales F,F,...]
                     [--delay N]
    sapga exemplars POLICY [--json] [--plot OUT.png] [--prune-unused OUT.json]
    sapga bench [--json] [--ros [--problem P] [--realtime]] [--style S] [--training [--steps N]]
    sapga inspect BAG [--json] [--plot OUT.png] [--episode N]
    sapga bag reindex BAG
    sapga experiment NAME --out DIR [--only 2,4] [--seeds N] [--scale F] [--workers W]
                     [--backend local|ray] [--address ADDR]
    sapga experiment report DIR
    sapga classical --problem P --out FILE.json [--gain NAME=V ...] [--c C]
    sapga limit --problem P [--alternative-goal] [--width W] [--json] [--out FILE]
    sapga limit --replay FILE.json [FILE.json ...] [--json]
    sapga launch NAME ... [--namespace NS] [--remap FROM:=TO ...] [--ros-args ...]
    sapga --version

``sapga`` finds the ament prefix it is installed in, so ``AMENT_PREFIX_PATH`` need not be
set by hand (``sapga_ros.launch.prefix``).

User errors (bad files, unknown problems, invalid numbers) print one line naming what is
wrong and exit with status 2; no traceback.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sapga_ros.cli.args import (add_param, bench_steps, check_output_file, episode_steps,
                                nonneg_int)
from sapga_ros.cli.classical import add_classical_arguments, cmd_classical
from sapga_ros.cli.experiment import (add_experiment_arguments, add_limit_arguments,
                                      cmd_experiment, cmd_limit)
from sapga_ros.cli.recordings import (add_bag_arguments, add_inspect_arguments, cmd_bag,
                                      cmd_inspect)
from sapga_ros.cli.robustness import add_robustness_arguments, cmd_robustness
from sapga_ros.cli.train import add_train_arguments, cmd_train
from sapga_ros import package_version
from sapga_ros.errors import SapgaError
from sapga_ros.io.jsonfile import dumps
from sapga_ros.policies.styles import STYLES
from sapga_ros.launch.prefix import ensure_ament_prefix
from sapga_ros.policies.classical import RUN_DELAY
from sim_nodes.options import add_settings
from sim_nodes.params import DELTA, build
from sapga_ros.evaluation.replan_settings import (JOBS as REPLAN_JOBS, ReplanSettings,
                                                  refuse_stray_settings, threads)

EXIT_USAGE = 2
POLICY_DELTA = "goal difficulty (default: the policy's training delta, else the problem's)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='sapga', description='Exemplar-based policy search (SAP-GA) for pendulums.')
    parser.add_argument('--version', action='version', version=f'%(prog)s {package_version()}')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    add_train_arguments(sub.add_parser(
        'train', help='evolve a policy (or run the Q-learning baseline)'))

    e = sub.add_parser('eval', help='run a policy\'s episode from the initial state')
    e.add_argument('policy', help='policy file (sapga-policy/1 or sapga-qtable/1)')
    add_param(e, DELTA, help=POLICY_DELTA)
    e.add_argument('--max-steps', type=episode_steps, help='N_step (default: the problem\'s)')
    e.add_argument('--json', action='store_true', help='print one JSON object')
    e.add_argument('--disturbance', metavar='NAME',
                   help='run --episodes episodes disturbed by this profile (a name in '
                        'msg_configs/disturbances or a .yaml file) and report the success '
                        'rate and the distributions of hold fraction, delta* and rail contacts')
    e.add_argument('--episodes', type=episode_steps, default=100,
                   help='disturbed episodes (default 100)')
    e.add_argument('--seed', type=nonneg_int, default=0,
                   help='seed of the disturbances drawn (default 0; never the draws a '
                        'training run used)')
    add_param(e, RUN_DELAY)
    e.add_argument('--replan', action='store_true',
                   help='re-plan the policy\'s own episode on the nominal model as it runs '
                        '(decision-time planning: the plan acts on the state predicted --delay '
                        'steps ahead); with --disturbance, its episodes; on a hold task the '
                        'planner aims at the classical LQR\'s region and hands over to it')
    add_settings(e, ReplanSettings)
    add_param(e, REPLAN_JOBS)

    x = sub.add_parser('exemplars', help='list, plot or prune a policy\'s exemplars')
    x.add_argument('policy')
    add_param(x, DELTA, help=POLICY_DELTA)
    x.add_argument('--json', action='store_true', help='print the list as JSON')
    x.add_argument('--plot', metavar='OUT.png', help='draw exemplars and the trajectory')
    x.add_argument('--prune-unused', metavar='OUT.json',
                   help='write a copy without the exemplars its episode never refers to')

    b = sub.add_parser('bench', help='batch evaluation speed vs a straightforward numba '
                                     'kernel and a plain NumPy loop')
    b.add_argument('--json', action='store_true', help='print one JSON object')
    b.add_argument('--ros', action='store_true',
                   help='instead: the lockstep loop through DDS and the policy node\'s '
                        'selection time (sapga_ros.bench.ros)')
    b.add_argument('--problem', default='acrobot', help='with --ros: the problem')
    b.add_argument('--realtime', action='store_true',
                   help='with --ros: also the realtime state->command latency (median, p99)')
    b.add_argument('--style', choices=(*STYLES, 'all'),
                   help='batch evaluation speed of this exemplar style (or all)')
    b.add_argument('--training', action='store_true',
                   help='instead: whole training runs, SAP-GA and Q-learning (alone and '
                        'seeds side by side), MDP steps/s (sapga_ros.bench.training)')
    b.add_argument('--steps', type=bench_steps, default=2_000_000,
                   help='with --training: MDP steps of each training run (default 2,000,000; '
                        'the paper\'s SAP-GA runs take 30,000,000)')

    add_inspect_arguments(sub.add_parser(
        'inspect', help='summarise (and plot) a recording: a bag directory or an MCAP file'))
    add_bag_arguments(sub.add_parser('bag', help='recording maintenance: bag reindex BAG'))

    add_experiment_arguments(sub.add_parser(
        'experiment', help='run an experiment set (table2, styles, ...) or write its report'))
    add_limit_arguments(sub.add_parser(
        'limit', help='the smallest delta any action sequence reaches (open-loop search)'))

    add_classical_arguments(sub.add_parser(
        'classical', help='write the classical controller (LQR behind an energy swing-up) '
        'as a policy file'))

    add_robustness_arguments(sub.add_parser(
        'robustness', help='success-rate curves of policies against each disturbance\'s size'))

    # `sapga launch ...` goes to the launch itself (main); listed here for `sapga --help`
    sub.add_parser('launch', help='start a group of nodes (swingup, train_deploy; sapga '
                   'launch --help)', add_help=False)
    return parser


def cmd_eval(args) -> int:
    from sapga_ros.evaluation.evaluator import run_policy_episode
    from sapga_ros.policies.classical import run_ahead, selector_delay
    from sapga_ros.policies.kinds import load_any_policy, policy_delta
    if args.replan:
        return _eval_replanned(args, load_any_policy(args.policy))
    refuse_stray_settings(args.given, args.replan)
    policy = run_ahead(load_any_policy(args.policy), args.delay, args.policy)
    delta = policy_delta(policy, args.delta)
    if args.disturbance:
        return _eval_disturbed(args, policy, delta)
    ep = run_policy_episode(policy, delta, args.max_steps)
    if args.json:
        print(dumps({**ep.summary(), 'delay': selector_delay(policy)}))
    else:
        reached = 'reached' if ep.reached else 'did not reach'
        print(f'{policy.problem.name}: return {ep.ret:.6f}, delta* {ep.delta_star:.6f}, '
              f'steps {ep.steps}, {reached} S_delta (delta {delta})')
        if not policy.problem.ends_in_goal or ep.contacts:
            hold = ep.summary()
            print(f'  first entry step {hold["first_entry_step"]}, hold fraction '
                  f'{hold["hold_fraction"]:.4f}, rail contacts {hold["rail_contacts"]}')
    return 0


def _eval_disturbed(args, policy, delta: float) -> int:
    from sapga_ros.evaluation.robust import robustness
    out = robustness(policy, delta, args.disturbance, args.episodes, args.seed, args.max_steps)
    if args.json:
        print(dumps(out))
        return 0
    print(f"{policy.problem.name} under {out['disturbance']}, {out['episodes']} episodes: "
          f"success {out['success_rate']:.3f} ({out['success']}), delta* median "
          f"{out['delta_star']['median']:.4f} (q90 {out['delta_star']['q90']:.4f}), hold "
          f"fraction mean {out['hold_fraction']['mean']:.3f}, rail contacts "
          f"{out['rail_contacts']['total']} in {out['rail_contacts']['episodes_with']} "
          'episodes')
    return 0


def _eval_replanned(args, policy) -> int:
    from sapga_ros.evaluation.replan import replanned
    from sapga_ros.evaluation.replan_settings import planner_delay
    from sapga_ros.policies.kinds import policy_delta
    delta = policy_delta(policy, args.delta)
    settings = build(ReplanSettings, lambda name: getattr(args, name))
    episodes = args.episodes if args.disturbance else 1
    jobs = threads(args.jobs)
    out = replanned(policy, delta, args.disturbance or 'none', episodes, args.seed, settings,
                    planner_delay(policy, args.delay), args.max_steps, jobs)
    if args.json:
        print(dumps(out))
        return 0
    print(f"{policy.problem.name} re-planned under {out['disturbance']}, {out['episodes']} "
          f"episodes: success {out['success_rate']:.3f} ({out['success']}), delta* median "
          f"{out['delta_star']['median']:.4f}, return median {out['return']['median']:.4f}")
    return 0


def cmd_exemplars(args) -> int:
    import numpy as np

    from sapga_ros.cli.exemplar_table import exemplar_table, format_table
    from sapga_ros.evaluation.evaluator import run_policy_episode
    from sapga_ros.policies.classical import same_controller
    from sapga_ros.policies.runnable import load_policy
    from sapga_ros.policies.kinds import policy_delta
    policy = load_policy(args.policy)
    delta = policy_delta(policy, args.delta)
    ep = run_policy_episode(policy, delta)
    reported = ep.exemplars[ep.exemplars >= 0]
    counts = np.bincount(reported, minlength=len(policy))
    rows = exemplar_table(policy, counts, ep.used)
    if args.json:
        print(dumps(rows))
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
        pruned = same_controller(policy, policy.subset(keep))   # keeps a catch or delay
        pruned.meta = {**policy.meta, 'pruned_from': str(args.policy)}
        pruned.save(args.prune_unused)
        print(f'pruned policy ({int(keep.sum())} exemplars): {args.prune_unused}',
              file=sys.stderr)
    return 0


def cmd_bench(args) -> int:
    if args.ros:
        from sapga_ros.bench.ros import main as bench_ros
        return bench_ros(['--problem', args.problem, '--processes',
                          *(['--realtime'] if args.realtime else [])])
    if args.style:
        return _bench_styles(args)
    if args.training:
        return _bench_training(args)
    from sapga_ros.bench.batch import run_bench
    result = run_bench()
    if args.json:
        print(dumps({k: v for k, v in result.items() if k != 'details'}))
        return 0
    for d in result['details']:
        print(f"{d['problem']:8s} batch: {d['steps_per_s_per_core'] / 1e6:6.3f} M steps/s per "
              f"core, {d['steps_per_s_all_cores'] / 1e6:6.3f} M steps/s on {d['threads']} "
              f"threads; NumPy loop: {d['numpy_steps_per_s']:8.0f} steps/s; speedup per core "
              f"{d['speedup_vs_numpy']:6.0f}x")
        if 'numba_steps_per_s' in d:
            print(f"{'':8s} straightforward numba kernel: {d['numba_steps_per_s'] / 1e6:6.3f} M "
                  f"steps/s; batch per core {d['speedup_vs_numba']:5.1f}x")
    return 0


def _bench_training(args) -> int:
    from sapga_ros.bench.training import QL_ROWS, SAPGA_ROWS, run_training_bench
    d = run_training_bench(args.steps)
    if args.json:
        print(dumps(d))
        return 0
    for problem, delta in SAPGA_ROWS:
        print(f'SAP-GA {problem:11s} delta {delta}: '
              f"{d[f'sapga_{problem}_steps_per_s'] / 1e6:6.3f} M steps/s (one thread, "
              f"whole run of {d['steps_per_run']:,} steps; "
              f"{d[f'sapga_{problem}_kernel_share']:.1%} of its CPU time in the batch kernel)")
    for problem, delta in QL_ROWS:
        print(f'QL     {problem:11s} delta {delta}: '
              f"{d[f'ql_{problem}_alone_steps_per_s'] / 1e6:6.3f} M steps/s alone, "
              f"{d[f'ql_{problem}_lanes_steps_per_s'] / 1e6:6.3f} M with {d['lanes']} seeds "
              f"side by side ({d[f'ql_{problem}_lanes_speedup']:.2f}x)")
    return 0


def _bench_styles(args) -> int:
    from sapga_ros.bench.batch import run_style_bench
    result = run_style_bench(list(STYLES) if args.style == 'all' else [args.style])
    if args.json:
        print(dumps(result))
        return 0
    for style, d in result.items():
        print(f"{style:18s} acrobot {d['acrobot_steps_per_s_per_core'] / 1e6:6.3f} M steps/s "
              f"per core ({d['acrobot_steps_per_s_all_cores'] / 1e6:6.3f} M on "
              f"{d['threads']} threads); pdip {d['pdip_steps_per_s_per_core'] / 1e6:6.3f} M "
              f"per core ({d['pdip_steps_per_s_all_cores'] / 1e6:6.3f} M)")
    return 0


def cmd_launch(argv: list[str]) -> int:
    """``sapga launch NAME args...``: the launch parses its own arguments (and --help)."""
    from sapga_ros.launch import run_launch
    return run_launch(argv[0] if argv else '', argv[1:])


COMMANDS = {'train': cmd_train, 'eval': cmd_eval, 'exemplars': cmd_exemplars,
            'bench': cmd_bench, 'inspect': cmd_inspect, 'bag': cmd_bag,
            'experiment': cmd_experiment, 'limit': cmd_limit, 'classical': cmd_classical,
            'robustness': cmd_robustness}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ensure_ament_prefix()
    if argv[:1] == ['launch']:
        return cmd_launch(argv[1:])
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
