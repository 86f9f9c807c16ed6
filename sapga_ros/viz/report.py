"""``DIR/report.md`` of an experiment directory (``sapga experiment report DIR``).

Everything comes from the directory's own files: ``summary.json`` (the table, Figures 3
and 4), ``runs/`` (the best policies of Figures 6 and 7), ``experiment.json`` (command,
wall time), ``limits/`` (physical limits, ``sapga limit --out``).  Figure 5 (state-action
map against a Q-learning map on mountain car) is trained here from fixed seeds, named in
the report, since no Table 2 row runs mountain car.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.analysis.limit_file import delta_text, read_limit
from sapga_ros.io.atomic import save_figure, write_atomic
from sapga_ros.policies.runnable import policy_from_document
from sapga_ros.training.experiment_report import count_text, hold_table, row_controls
from sapga_ros.training.report_files import read_info, read_summary
from sapga_ros.training.run_files import run_path, stored_runs
from sapga_ros.viz.quiet import quiet_drawing

FIG5_STEPS = 1_000_000      # MDP steps of each Figure 5 run (SAP-GA and Q-learning), seed 0


def _pm(mean: float | None, std: float | None, digits: int) -> str:
    if mean is None or std is None or not math.isfinite(mean):
        return 'n/a'
    return f'{mean:.{digits}f} ± {std:.{digits}f}'


def _ci(ci: list | None, digits: int) -> str:
    return f'[{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]' if ci else 'n/a'


def _row(s: dict) -> str:
    f = s['final']
    method = s['method'].upper() if s['method'] != 'sapga' else 'SAP-GA'
    if s['method'] == 'sapga' and s.get('style', 'state-action') != 'state-action':
        method += f" ({s['style']})"
    if s['method'] == 'sapga' and s.get('variant', 'paper') != 'paper':
        method += f" [{s['variant']}]"
    method += row_controls(s)
    alt = ''
    if 'delta_star_alt_mean' in f:
        alt = (f"{_pm(f['delta_star_alt_mean'], f['delta_star_alt_std'], 4)}, achieved "
               f"{count_text(f['achieved_alt'], f['runs'], f, 'achieved_alt')}")
    greedy = _pm(f.get('greedy_delta_star_mean'), f.get('greedy_delta_star_std'), 4) \
        if 'greedy_delta_star_mean' in f else ''
    return (f"| #{s['id']} | {s['problem']}, δ = {s['delta']} | {method} | {s['steps']:,d} | "
            f"{s.get('paper', '')} | **{count_text(f['achieved'], f['runs'], f)}** | "
            f"{_pm(f['delta_star_mean'], f['delta_star_std'], 4)} "
            f"{_ci(f.get('delta_star_ci95'), 4)} | "
            f"{_pm(f['best_value_mean'], f['best_value_std'], 1)} "
            f"{_ci(f.get('best_value_ci95'), 1)} | {alt} | {greedy} |")


def _returned_row(s: dict) -> str:
    f = s['final']
    if 'policy_value_mean' not in f:
        return f"| #{s['id']} | {s['problem']} | n/a (runs from before these measures) |"
    return (f"| #{s['id']} | {s['problem']}, δ = {s['delta']} | "
            f"{_pm(f['policy_value_mean'], f['policy_value_std'], 1)} "
            f"{_ci(f.get('policy_value_ci95'), 1)} | "
            f"{_pm(f['policy_delta_star_mean'], f['policy_delta_star_std'], 4)} "
            f"{_ci(f.get('policy_delta_star_ci95'), 4)} | "
            f"{count_text(f['policy_reached'], f['runs'], f, 'policy_reached')} | "
            f"{f['policy_rail_runs']}/{f['runs']} ({f['policy_rail_contacts_mean']:.1f}) |")


def table(summaries: list[dict]) -> list[str]:
    """The results table: the paper's claim beside ours, per experiment (achieved: runs
    whose delta* over every episode they evaluated reached delta, with a Wilson 95 %
    interval), then the returned policies' own episodes."""
    head = ['| # | problem | method | steps | paper | achieved [95 % CI] | run δ* (mean ± std, '
            '95 % CI) | run best value (mean ± std, 95 % CI) | δ* under \\|v\\| ≤ 32δ | '
            'QL greedy δ* |', '|---|---|---|---|---|---|---|---|---|---|']
    own = ['', 'The returned policy of each run, its own episode (not the run\'s bests):', '',
           '| # | problem | value (mean ± std, 95 % CI) | δ* (mean ± std, 95 % CI) | '
           'reaches S_δ [95 % CI] | runs with rail contacts (mean contacts) |',
           '|---|---|---|---|---|---|']
    return head + [_row(s) for s in summaries] + own + [_returned_row(s) for s in summaries]


def _best_runs(out: Path, summary: dict, count: int) -> list[tuple[dict, dict]]:
    """The ``count`` runs of an experiment with the best final value, with their policy."""
    runs = []
    for _, run in stored_runs(out, summary['id'], summary['seeds']):
        if math.isfinite(run['final']['best_value']) and 'policy' in run:
            runs.append(run)
            runs.sort(key=lambda r: -r['final']['best_value'])
            del runs[count:]                       # one run beyond those kept in memory
    return [(r, r['policy']) for r in runs]


@quiet_drawing()
def _trajectory_figure(out: Path, name: str, episodes: list, problem, delta: float,
                       titles: list[str]) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from sapga_ros.viz.episode_plot import draw_strobe
    fig, axes = plt.subplots(1, len(episodes), figsize=(6 * len(episodes), 5), squeeze=False)
    for ax, ep, title in zip(axes[0], episodes, titles):
        draw_strobe(ax, problem, ep.states, delta)
        ax.set_title(title, fontsize='small')
    fig.tight_layout()
    path = save_figure(fig, out, name)
    plt.close(fig)
    return path


def _upright_step(problem, ep, delta: float) -> str:
    return f'reaches S_δ (δ = {delta}) at step {ep.steps}' if ep.reached else \
        f'does not reach S_δ in {ep.steps} steps (δ* {ep.delta_star:.4f})'


def trajectory_figures(out: Path, summaries: list[dict]) -> list[str]:
    """Figure 6 (the best acrobot SAP-GA policy) and Figure 7 (two PDIP SAP-GA policies)."""
    lines = []
    for fig, family, count in (('figure6_acrobot.png', 'acrobot', 1),
                               ('figure7_pdip.png', 'pdip', 2)):
        rows = [s for s in summaries if s['problem'] == family and s['method'] == 'sapga'
                and s.get('group', 'paper') == 'paper']
        if not rows:
            continue
        best = _best_runs(out, rows[0], count)
        if not best:
            continue
        episodes, titles = [], []
        for run, doc in best:
            policy = policy_from_document(
                doc, family, f"{run_path(out, rows[0]['id'], run['seed'])}: run.policy")
            ep = Evaluator(policy.problem, rows[0]['delta']).episode(policy)
            episodes.append(ep)
            titles.append(f"#{rows[0]['id']} seed {run['seed']}: return {ep.ret:.1f}, "
                          f'{_upright_step(policy.problem, ep, rows[0]["delta"])}')
        path = _trajectory_figure(out, fig, episodes, episodes and policy.problem,
                                  rows[0]['delta'], titles)
        number = 6 if family == 'acrobot' else 7
        lines += [f'**Figure {number}** ({family}, the best '
                  f'{"policy" if count == 1 else f"{count} policies"} of #{rows[0]["id"]} '
                  'by final value): ' + '; '.join(titles), '', f'![Figure {number}]({path.name})',
                  '']
    return lines


def figure5(out: Path) -> list[str]:
    """Mountain car: a SAP-GA state-action policy's map beside a Q-learning policy's."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from sapga_ros.policies.qtable import cell_index, greedy
    from sapga_ros.training.loop import TrainConfig, train
    from sapga_ros.viz.exemplar_plot import policy_map
    runs = {m: train(TrainConfig(problem='mountain_car', method=m, steps=FIG5_STEPS, seed=0))
            for m in ('sapga', 'ql')}
    sapga, table_ = runs['sapga'].policy, runs['ql'].policy
    xs, ys, grid = policy_map(sapga)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    axes[0].pcolormesh(xs, ys, grid, cmap='Greys', shading='auto', vmin=-1, vmax=1.5)
    for a, marker in zip(range(len(sapga.problem.actions)), ('s', '^')):
        sel = sapga.actions == a
        axes[0].scatter(sapga.states[sel, 0], sapga.states[sel, 1], marker=marker,
                        facecolors='none', edgecolors='tab:blue', s=18)
    ep = Evaluator(sapga.problem, 0.0).episode(sapga)
    axes[0].plot(ep.states[:, 0], ep.states[:, 1], 'r-', lw=1)
    axes[0].set_title(f'SAP-GA (state-action): {len(sapga)} exemplars, goal at step '
                      f'{ep.steps}', fontsize='small')
    idx, low, width, tiles = table_.tiling
    qgrid = np.array([[table_.problem.action_values[
        greedy(table_.q, cell_index(np.array([x, y]), idx, low, width, tiles))]
        for x in xs] for y in ys])               # the kernels' own tiling and greedy choice
    axes[1].pcolormesh(xs, ys, qgrid, cmap='Greys', shading='auto', vmin=-1, vmax=1.5)
    qep = table_.episode(0.0)
    axes[1].plot(qep.states[:, 0], qep.states[:, 1], 'r-', lw=1)
    axes[1].set_title(f'Q-learning ({tiles}x{tiles} tiles): goal '
                      f'{"at step " + str(qep.steps) if qep.reached else "not reached"}',
                      fontsize='small')
    for ax in axes:
        ax.set_xlabel('x [m]')
        ax.set_ylabel('v [m/step]')
    fig.tight_layout()
    path = save_figure(fig, out, 'figure5_mountain_car.png')
    plt.close(fig)
    return ['**Figure 5** (mountain car; action +1 in the dark area, -1 in the light; '
            f'triangles and squares: exemplars; red: the trajectory).  Trained for this '
            f'report: `sapga train --problem mountain_car --method sapga|ql --steps '
            f'{FIG5_STEPS} --seed 0`.', '', f'![Figure 5]({path.name})', '']


def limits(out: Path) -> list[str]:
    """The physical limits found (``sapga limit --out DIR/limits/NAME.json``): every
    search's sequence scored under every goal reading (``sapga limit --replay``), with its
    rail contacts, then per problem and reading the best over all searches."""
    from sapga_ros.analysis.limit_replay import replay
    from sim_nodes.problem import load_problem
    files = sorted((out / 'limits').glob('*.json')) if (out / 'limits').is_dir() else []
    if not files:
        return []
    lines = ['| search | searched under | δ as printed (step) | δ alternative (step) | '
             'rail contacts on the way (steps) | beam |', '|---|---|---|---|---|---|']
    best: dict[tuple[str, str], tuple] = {}
    for path in files:
        d = read_limit(path)
        scores = {r.reading: r for r in replay(load_problem(d['problem']), d['actions'])}
        for r in scores.values():
            key = (d['problem'], r.reading)
            if key not in best or r.delta < best[key][0].delta:
                best[key] = (r, path.name)
        cells = [f'{delta_text(scores[k].delta)} ({scores[k].step})' if k in scores else '–'
                 for k in ('printed', 'alternative')]
        last = max(scores.values(), key=lambda r: r.step)
        contacts = ', '.join(map(str, last.contact_steps)) or '-'
        under = 'alternative (\\|v\\| ≤ 32δ)' if d['alternative_goal'] else 'as printed'
        lines.append(f"| {d['problem']} (`{path.name}`) | {under} | {cells[0]} | {cells[1]} "
                     f"| {last.rail_contacts} ({contacts}) | {d['width']:,d} wide, "
                     f"{d['cells']} cells, {d['steps_simulated']:,d} steps |")
    lines += ['', 'Best over all searches (upper bounds: what a search found):', '',
              '| problem | goal box | smallest δ found | at step | from | rail contacts |',
              '|---|---|---|---|---|---|']
    for (problem, reading), (r, name) in sorted(best.items()):
        lines.append(f'| {problem} | {reading} | {delta_text(r.delta)} | {r.step} | '
                     f'`{name}` | {r.rail_contacts} |')
    return lines + ['']


def write_report(out: Path, with_figure5: bool = True, curves=None) -> Path:
    """Write ``out/report.md`` from the directory's files; return its path.  ``curves``
    (``report_robustness.CurveSettings``): also measure and draw robustness curves."""
    from sapga_ros.viz.summary_plot import plot_summaries
    if not (out / 'summary.json').is_file():
        raise SapgaError(f'{out}: no summary.json (not an experiment directory, or its runs '
                         'have not finished)')
    summaries = read_summary(out / 'summary.json')
    info = read_info(out / 'experiment.json') if (out / 'experiment.json').exists() else {}
    lines = [f"# Experiment report: {info.get('name', out.name)}", '']
    if info:
        lines += [f"Command: `{info.get('command', '')}`", '',
                  f"Wall time of the last invocation: {info.get('wall_s', math.nan):.0f} s "
                  f"({info.get('runs_run', '?')} runs run, {info.get('runs_reused', '?')} "
                  f"reused from runs/); backend {info.get('backend', 'local')}.", '']
    groups = {}
    for s in summaries:
        groups.setdefault(s.get('group', 'paper'), []).append(s)
    titles = {'paper': 'Results', 'ablation': 'Ablation: SAP-GA variants', 'peer': 'Peers'}
    for group, rows in groups.items():
        lines += [f'## {titles.get(group, group)}', ''] + table(rows) + ['']
    held = hold_table(summaries)
    if held:
        lines += ['## Hold', '', 'Each run\'s returned policy, its own episode: hold '
                  'fraction (steps in S_δ from the first entry on / steps from it to the end; '
                  'mean ± std, 95 % bootstrap interval), runs holding >= 0.95, runs holding '
                  '>= 0.9 with no rail contact, first entry step (mean over the runs that '
                  'entered), rail contacts (mean).'] + held + ['']
    if curves is not None:
        from sapga_ros.viz.report_robustness import robustness_section
        lines += ['## Robustness', ''] + robustness_section(out, summaries, curves)
    lim = limits(out)
    if lim:
        lines += ['## Physical limits (open-loop search)', ''] + lim
    lines += ['## Figures', '']
    for path in plot_summaries(summaries, out):
        lines += [f'![{path.stem}]({path.name})', '']
    lines += trajectory_figures(out, summaries)
    from sapga_ros.viz.hold_plot import hold_figures
    lines += hold_figures(out, summaries)
    if with_figure5:
        lines += figure5(out)
    path = out / 'report.md'
    write_atomic(path, '\n'.join(lines) + '\n')
    return path
