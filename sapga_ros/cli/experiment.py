"""``sapga experiment`` and ``sapga limit``: experiment sets (local or on Ray), their report,
and the physical limit of a problem.

    sapga experiment NAME --out DIR [--only 2,4] [--seeds N] [--scale F] [--workers W]
                     [--backend local|ray] [--address ADDR] [--robustness NAME[,NAME]
                     [--robustness-scales F,F] [--robustness-episodes N]
                     [--robustness-replan [--replan-fit X ...]]]
    sapga experiment report DIR [--robustness ...]
    sapga limit --problem P [--alternative-goal] [--width W] [--cells C] [--per-cell K]
                [--seed S] [--json] [--out FILE.json]
    sapga limit --replay FILE.json [FILE.json ...] [--json]
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from sapga_ros.cli.args import episode_steps, nonneg_int, positive_int
from sapga_ros.cli.robustness import PROFILES, scale_list
from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.replan_settings import ReplanSettings, refuse_stray_settings, threads
from sapga_ros.training.experiment_set import MAX_SCALE, MAX_SEEDS
from sim_nodes.options import add_settings
from sim_nodes.params import build


MAX_WORKERS = 4096


def _at_most(parse, high: int, what: str):
    """An argparse type: ``parse`` of the text, at most ``high``."""
    def check(text: str) -> int:
        value = parse(text)
        if value > high:
            raise argparse.ArgumentTypeError(f'expected at most {high} {what}, got {text!r}')
        return value
    return check


seed_count = _at_most(positive_int, MAX_SEEDS, 'seeds')
worker_count = _at_most(nonneg_int, MAX_WORKERS, 'workers')


def scale_value(text: str) -> float:
    """An argparse type: a step-budget factor in (0, MAX_SCALE]."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0 < value <= MAX_SCALE):
        raise argparse.ArgumentTypeError(f'expected a number in (0, {MAX_SCALE:g}], '
                                         f'got {text[:40]!r}')
    return value


def add_experiment_arguments(ex: argparse.ArgumentParser) -> None:
    ex.add_argument('name', help='msg_configs/experiments/<name>.yaml (table2, beyond, '
                                 'styles, hold, robust), or "report" to rewrite DIR/report.md '
                                 'from its runs')
    ex.add_argument('dir', nargs='?', help='with report: the experiment directory')
    ex.add_argument('--out', help='directory for runs/, summary.json, report.md, figures')
    ex.add_argument('--only', help='comma-separated experiment ids, e.g. 2,4')
    ex.add_argument('--seeds', type=seed_count,
                    help='seeds per experiment (default: the set\'s, 20 for table2)')
    ex.add_argument('--scale', type=scale_value, default=1.0,
                    help='multiply every step budget (e.g. 0.1 for a quick look)')
    ex.add_argument('--workers', type=worker_count, default=0,
                    help='parallel runs (default 0: every core)')
    ex.add_argument('--backend', choices=('local', 'ray'), default='local',
                    help='local worker processes, or tasks on a Ray cluster')
    ex.add_argument('--address', help='with --backend ray: a running cluster (default: start '
                                      'a local Ray instance)')
    ex.add_argument('--robustness', metavar='NAME[,NAME]',
                    help='also measure each row\'s returned policies against these disturbance '
                         'profiles (e.g. field,latency; "default": sensor,latency,mismatch,'
                         'push,field) and draw success-rate curves in the report')
    ex.add_argument('--robustness-scales', type=scale_list, default=[0.0, 0.5, 1.0, 2.0],
                    metavar='F,F', help='with --robustness: size factors (default 0,0.5,1,2)')
    ex.add_argument('--robustness-episodes', type=episode_steps, default=20, metavar='N',
                    help='with --robustness: held-out episodes per policy and size '
                         '(default 20)')
    ex.add_argument('--robustness-replan', action='store_true',
                    help='with --robustness: the curves of the policies\' plans re-planned as '
                         'they run (as sapga eval --replan, predicting for each size\'s '
                         'latency; on every core)')
    add_settings(ex, ReplanSettings)


def cmd_experiment(args) -> int:
    from sapga_ros.training.experiments import run_experiments
    from sapga_ros.viz.report import write_report
    curves = _curves(args)
    if args.name == 'report':
        if not args.dir:
            raise SapgaError('experiment report needs the experiment directory')
        path = write_report(Path(args.dir), curves=curves)
        print(f'report: {path}')
        return 0
    if args.dir:
        raise SapgaError(f'unexpected argument {args.dir!r} (the directory is --out DIR)')
    if not args.out:
        raise SapgaError('--out DIR is required')
    if args.address and args.backend != 'ray':
        raise SapgaError('--address is for --backend ray')
    only = None
    if args.only:
        try:
            only = [int(x) for x in args.only.split(',') if x.strip()]
        except ValueError:
            raise SapgaError(f'--only: expected comma-separated ids, got {args.only[:40]!r}')
    run_experiments(args.name, args.out, only, args.seeds, args.scale, args.workers or None,
                    backend=args.backend, address=args.address)
    path = write_report(Path(args.out), curves=curves)
    print(f'report: {path}')
    return 0


def _curves(args):
    """The robustness curves the options ask for (None: none)."""
    from sapga_ros.viz.report_robustness import CurveSettings
    refuse_stray_settings(args.given, args.robustness_replan)
    if args.robustness_replan and not args.robustness:
        raise SapgaError('--robustness-replan is a setting of --robustness')
    if not args.robustness:
        return None
    names = [n.strip() for n in args.robustness.split(',') if n.strip()]
    if names == ['default']:
        names = list(PROFILES)
    if not names or len(names) > 20:
        raise SapgaError(f'--robustness: expected 1 to 20 profile names, got '
                         f'{args.robustness[:40]!r}')
    from sim_nodes.disturbance import load_disturbance
    for name in names:
        load_disturbance(name)            # an unknown name: one line, before any run
    replan = (build(ReplanSettings, lambda name: getattr(args, name))
              if args.robustness_replan else None)
    return CurveSettings(tuple(names), tuple(args.robustness_scales),
                         args.robustness_episodes, replan=replan, jobs=threads(0))


def add_limit_arguments(li: argparse.ArgumentParser) -> None:
    li.add_argument('--problem', help='problem name (the search)')
    li.add_argument('--replay', nargs='+', metavar='FILE',
                    help='instead of a search: replay the action sequences of these limit '
                         'files under every goal reading (delta, step, rail contacts)')
    li.add_argument('--alternative-goal', action='store_true',
                    help='use the problem\'s alternative goal reading (PDIP: |v| <= 32 delta)')
    li.add_argument('--width', type=positive_int, default=50_000, help='beam width')
    li.add_argument('--cells', type=positive_int, default=32,
                    help='grid cells per state coordinate')
    li.add_argument('--per-cell', type=positive_int, default=4,
                    help='children kept per grid cell')
    li.add_argument('--seed', type=nonneg_int, default=0, help='random seed')
    li.add_argument('--json', action='store_true', help='print one JSON object')
    li.add_argument('--out', help='also write the result (with its action sequence) here')


def cmd_limit(args) -> int:
    from sapga_ros.analysis.limit import beam_limit
    from sapga_ros.analysis.limit_file import limit_document
    from sapga_ros.io.jsonfile import dumps, write_json
    from sim_nodes.goal import alternative_goal
    from sim_nodes.problem import load_problem
    if args.replay:
        if args.problem or args.out or args.alternative_goal:
            raise SapgaError('--replay takes the problem and goal from its files (no '
                             '--problem, --alternative-goal or --out)')
        return _replay(args.replay, args.json)
    if not args.problem:
        raise SapgaError('limit needs --problem NAME (a search) or --replay FILE')
    problem = load_problem(args.problem)
    if args.alternative_goal:
        if alternative_goal(problem) is None:
            raise SapgaError(f'{problem.name} has no alternative goal reading')
        problem = alternative_goal(problem)
    limit = beam_limit(problem, width=args.width, cells=args.cells, per_cell=args.per_cell,
                       seed=args.seed)
    doc = {**limit_document(limit), 'alternative_goal': args.alternative_goal}
    if args.out:
        write_json(Path(args.out), doc)
    if args.json:
        print(dumps({k: v for k, v in doc.items() if k != 'actions'}))
    else:
        print(f'{problem.name}: smallest delta found {limit.delta:.6f} at step {limit.step} '
              f'({limit.steps_simulated:,d} MDP steps simulated; width {limit.width}, '
              f'{limit.cells} cells per coordinate)')
    return 0


def _replay(files: list[str], as_json: bool) -> int:
    """``sapga limit --replay``: each file's sequence scored under every goal reading."""
    from sapga_ros.analysis.limit_file import read_limit
    from sapga_ros.analysis.limit_replay import replay
    from sapga_ros.io.jsonfile import dumps
    from sim_nodes.problem import load_problem
    found = []
    for name in files:
        doc = read_limit(name)
        scores = replay(load_problem(doc['problem']), doc['actions'])
        found.append((name, doc, scores))
    if as_json:
        print(dumps([{'file': name, 'problem': doc['problem'],
                      'searched_under': 'alternative' if doc['alternative_goal'] else 'printed',
                      'steps': doc['step'],
                      'readings': [{'reading': r.reading, 'delta': r.delta, 'step': r.step,
                                    'rail_contacts': r.rail_contacts,
                                    'contact_steps': list(r.contact_steps)} for r in scores]}
                     for name, doc, scores in found]))
        return 0
    for name, doc, scores in found:
        under = 'alternative' if doc['alternative_goal'] else 'printed'
        print(f"{name}: {doc['problem']}, {doc['step']} actions, searched under the "
              f'{under} goal box')
        for r in scores:
            where = ', '.join(map(str, r.contact_steps)) if r.contact_steps else '-'
            print(f'  {r.reading:<11} delta {r.delta:.6f} at step {r.step}; rail contacts '
                  f'before it: {r.rail_contacts} (steps {where})')
    return 0
