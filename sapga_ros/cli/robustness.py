"""``sapga robustness``: success-rate curves of policies against each disturbance's size.

    sapga robustness POLICY [POLICY ...] --out DIR [--disturbance NAME ...]
                     [--scales 0,0.5,1,2,4] [--episodes N] [--seed S]
                     [--replan [--replan-fit X ...] [--jobs N]]

Each profile (default: sensor, latency, mismatch, push, field) is scaled by every factor of
``--scales`` (``Disturbance.scaled``: sizes times the factor, latency rounded to whole
steps); each policy runs ``--episodes`` held-out disturbed episodes at each size.  Writes
``DIR/robustness.json`` (every point: success rate, hold fraction and delta* summaries) and
``DIR/<profile>.png``, one figure per profile with one curve per policy.  With ``--replan``
the curves are those of the policies' plans re-planned as they run (``sapga eval
--replan``), the planner predicting for ``--delay`` steps, or with ``--delay`` 0 for each
point's own latency.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from sapga_ros.cli.args import check_output_dir, episode_steps, nonneg_int
from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.replan_settings import (JOBS as REPLAN_JOBS, ReplanSettings,
                                                  check_plannable, refuse_stray_settings,
                                                  threads)
from sapga_ros.policies.classical import RUN_DELAY
from sim_nodes.options import add_param, add_settings
from sim_nodes.params import build

PROFILES = ('sensor', 'latency', 'mismatch', 'push', 'field')


def scale_list(text: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(',')]
    except ValueError:
        values = []
    if not values or not all(0 <= v <= 1000 for v in values):
        raise argparse.ArgumentTypeError(f'expected numbers in [0, 1000] separated by commas, '
                                         f'got {text!r}')
    return values


def add_robustness_arguments(r: argparse.ArgumentParser) -> None:
    r.add_argument('policies', nargs='+', metavar='POLICY', help='policy files of one problem')
    r.add_argument('--out', required=True, metavar='DIR', help='folder for the figures and '
                   'robustness.json (created if missing)')
    r.add_argument('--disturbance', action='append', metavar='NAME',
                   help=f'profile to sweep (repeatable; default: {", ".join(PROFILES)})')
    r.add_argument('--scales', type=scale_list, default=[0.0, 0.5, 1.0, 2.0, 4.0],
                   help='size factors (default 0,0.5,1,2,4)')
    r.add_argument('--episodes', type=episode_steps, default=50,
                   help='disturbed episodes per policy and size (default 50)')
    r.add_argument('--seed', type=nonneg_int, default=0, help='seed of the draws (default 0)')
    add_param(r, RUN_DELAY, help='run every exemplar policy as designed for N MDP steps of '
              'actuation delay (its selector acts on the state predicted that far ahead); 0: '
              'as each file says (default 0).  With --replan: the delay the planner predicts '
              'for; 0: the latency of each point\'s plant')
    r.add_argument('--replan', action='store_true',
                   help='the curves of each policy\'s plan re-planned as it runs (as sapga eval '
                        '--replan; a hold task hands over to the classical LQR)')
    add_settings(r, ReplanSettings)
    add_param(r, REPLAN_JOBS)


def cmd_robustness(args: argparse.Namespace) -> int:
    from sapga_ros.evaluation.sweep import sweep
    from sapga_ros.io.jsonfile import dumps
    from sapga_ros.io.atomic import write_inside
    from sapga_ros.policies.classical import run_ahead
    from sapga_ros.policies.kinds import load_any_policy, policy_delta
    from sapga_ros.viz.robustness_plot import curve_figures
    from sim_nodes.disturbance import load_disturbance
    out = Path(args.out)
    check_output_dir(out, '--out')
    refuse_stray_settings(args.given, args.replan)
    if args.replan:
        policies = [load_any_policy(p) for p in args.policies]
        for p in policies:
            check_plannable(p.problem)
        replan = build(ReplanSettings, lambda name: getattr(args, name))
    else:
        policies = [run_ahead(load_any_policy(p), args.delay, p) for p in args.policies]
        replan = None
    if len({p.problem.name for p in policies}) > 1:
        raise SapgaError('robustness curves compare policies of one problem')
    jobs = threads(args.jobs)
    profiles = [load_disturbance(name) for name in args.disturbance or PROFILES]
    results, curves = [], {}
    for profile in profiles:
        for f, policy in zip(args.policies, policies):
            rows = [{**r, 'policy': f} for r in sweep(
                policy, policy_delta(policy), profile, args.scales, args.episodes, args.seed,
                replan, args.delay, jobs)]
            results += rows
            curves.setdefault(profile.name, {})[Path(f).stem] = [
                (r['scale'], r['success_rate'], None) for r in rows]
            print(f'{profile.name} {f}: success ' + ', '.join(
                f"x{r['scale']:g} {r['success_rate']:.2f}" for r in rows), flush=True)
    out.mkdir(parents=True, exist_ok=True)
    write_inside(out, 'robustness.json', dumps(results, indent=1))
    success = results[0]['success'] if results else 'success'
    curve_figures(curves, out, '', f'success rate ({success})',
                  f'{args.episodes} episodes a point' + (', re-planned' if replan else ''))
    print(f'wrote {out}/robustness.json and {len(profiles)} figures')
    return 0
