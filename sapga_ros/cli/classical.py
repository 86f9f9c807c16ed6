"""``sapga classical``: write the classical controller of a problem as a policy file.

    sapga classical --problem P --out FILE.json [--gain NAME=VALUE ...] [--c C] [--delay D]

The LQR about the upright state (the model linearised at the compiled MDP step) behind the
model's energy swing-up, its action quantised to the problem's action set
(``sapga_ros.policies.classical``).  The file is a policy of kind ``classical`` that
``sapga eval``, the policy node and ``sapga launch swingup`` run like any policy; its
episode from the initial state is evaluated and stored in ``meta`` (with ``--delay D``, on
the plant that applies each command D steps late, which the controller is designed for).
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from sapga_ros.cli.args import add_param, check_output_file


def _gain(text: str) -> tuple[str, float]:
    name, sep, value = text.partition('=')
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number):
        raise argparse.ArgumentTypeError(f'expected NAME=NUMBER, got {text!r}')
    return name, number


def _catch(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'expected a finite number >= 0, got {text!r}')
    return value


def add_classical_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--problem', required=True, help='problem name (msg_configs)')
    parser.add_argument('--out', required=True, metavar='FILE.json', help='policy file')
    parser.add_argument('--gain', type=_gain, action='append', default=[], metavar='NAME=V',
                        help='override a swing-up gain (acrobot: kp, kd, ke; cart: ke, kx, kv)')
    parser.add_argument('--c', type=_catch, help='catch region x\'Px <= c (default: the '
                        'design\'s margin x the measured basin)')
    from sapga_ros.policies.classical import DELAY
    add_param(parser, DELAY)


def cmd_classical(args) -> int:
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.evaluation.classical_design import classical_policy
    from sim_nodes.disturbance import Disturbance
    from sim_nodes.problem import load_problem
    check_output_file(Path(args.out), '--out')
    problem = load_problem(args.problem)
    policy = classical_policy(problem, dict(args.gain), args.c, delay=args.delay)
    late = Disturbance(latency=args.delay) if args.delay else None
    ep = Evaluator(problem, disturbance=late).episode(policy)
    summary = ep.summary()
    policy.meta.update({'delta': problem.default_delta, 'value': ep.ret,
                        'delta_star': ep.delta_star, **summary, 'gains': policy.gains,
                        'c': policy.c, **({'latency': args.delay} if args.delay else {})})
    policy.save(args.out)
    late_text = f' (latency {args.delay})' if args.delay else ''
    print(f'{problem.name}: classical controller{late_text} -> {args.out}: return {ep.ret:.3f}, '
          f'delta* {ep.delta_star:.4f}, first entry step {summary["first_entry_step"]}, '
          f'hold fraction {summary["hold_fraction"]:.4f}, rail contacts '
          f'{summary["rail_contacts"]}')
    return 0
