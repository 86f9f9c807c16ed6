"""Summaries of an experiment's runs: curves against steps averaged over seeds,
the final measures and a Markdown table.  The figures drawn from them, like the paper's
Figures 3 and 4, are in ``sapga_ros.viz.summary_plot``.
"""
from __future__ import annotations

import math
import warnings
from typing import Iterable

import numpy as np

from sapga_ros.training.experiment_set import Experiment

GRID_POINTS = 100


def resample(steps: list[int], values: list[float], grid: np.ndarray) -> np.ndarray:
    """The logged value in force at each grid step (nan before the first log row)."""
    idx = np.searchsorted(np.asarray(steps), grid, side='right') - 1
    vals = np.asarray(values, dtype=float)
    return np.where(idx >= 0, vals[np.clip(idx, 0, None)], np.nan)


def _nulls(a: np.ndarray) -> list:
    """A list for JSON: nan (no data) becomes null."""
    return [None if not math.isfinite(v) else float(v) for v in a]


def _mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and standard deviation (nan for no values, or when one is not finite)."""
    if not values:
        return math.nan, math.nan
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        return float(np.mean(values)), float(np.std(values))


def summarise(exp: Experiment, runs: Iterable[dict], budget: int) -> dict:
    """The summary of an experiment's runs (checked run records, ``training.run_files``),
    taken one at a time: only their curves on the grid and final measures are kept.  A run
    counts as achieved when its delta* is a number <= delta (never a nan)."""
    grid = np.linspace(budget / GRID_POINTS, budget, GRID_POINTS)
    best_rows, dstar_rows, finals, seeds, seconds = [], [], [], [], 0.0
    for r in runs:
        best_rows.append(resample(r['steps'], r['best_value'], grid))
        dstar_rows.append(resample(r['steps'], r['delta_star'], grid))
        finals.append(r['final'])
        seeds.append(r['seed'])
        seconds += r.get('seconds', math.nan)
    best = np.array(best_rows).reshape(len(finals), GRID_POINTS)
    dstar = np.array(dstar_rows).reshape(len(finals), GRID_POINTS)
    dstar = np.where(np.isfinite(dstar), dstar, np.nan)
    achieved = (dstar <= exp.delta).astype(float)

    def stat(a):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # all-nan columns: no run yet
            return {'mean': _nulls(np.nanmean(a, axis=0)), 'std': _nulls(np.nanstd(a, axis=0))}
    best_final = [f['best_value'] for f in finals]
    dstar_final = [f['delta_star'] for f in finals]
    best_mean, best_std = _mean_std(best_final)
    dstar_mean, dstar_std = _mean_std(dstar_final)
    final = {'best_value_mean': best_mean, 'best_value_std': best_std,
             'delta_star_mean': dstar_mean, 'delta_star_std': dstar_std,
             'achieved': sum(_reaches(d, exp.delta) for d in dstar_final),
             'runs': len(finals),
             'best_value_ci95': bootstrap_ci(best_final),
             'delta_star_ci95': bootstrap_ci(dstar_final)}
    final['achieved_ci95'] = wilson_ci(final['achieved'], len(finals))
    for key in ('delta_star_alt', 'greedy_delta_star'):
        values = [f[key] for f in finals if f.get(key) is not None and math.isfinite(f[key])]
        if finals and len(values) == len(finals):
            mean, std = _mean_std(values)
            final.update({f'{key}_mean': mean, f'{key}_std': std,
                          f'{key}_ci95': bootstrap_ci(values)})
            if key == 'delta_star_alt':
                final['achieved_alt'] = sum(_reaches(v, exp.delta) for v in values)
                final['achieved_alt_ci95'] = wilson_ci(final['achieved_alt'], len(finals))
    if finals and all('policy_value' in f for f in finals):
        final.update(returned_summary(finals))
    if all('hold_fraction' in f for f in finals):
        final.update(hold_summary(finals))
    return {'id': exp.id, 'problem': exp.problem, 'method': exp.method, 'delta': exp.delta,
            'style': exp.style, 'variant': exp.variant, 'catch': exp.catch,
            'catch_delay': exp.catch_delay, 'delay': exp.delay,
            'disturbance': exp.disturbance, 'episodes': exp.episodes, 'redraw': exp.redraw,
            'paper': exp.paper,
            'group': exp.group,
            'steps': budget, 'seeds': seeds, 'grid': grid.tolist(),
            'best_value': stat(best), 'delta_star': stat(dstar),
            'achieved_fraction': achieved.mean(axis=0).tolist(), 'final': final,
            # wall-clock speed of the runs: the one measure that differs between machines
            'timing': {'steps_per_s_mean': _mean_std([f.get('steps_per_s', math.nan)
                                                      for f in finals])[0],
                       'seconds_total': seconds}}


def _reaches(delta_star: float, delta: float) -> bool:
    """Whether a run's delta* achieves ``delta`` (a nan never does)."""
    return bool(math.isfinite(delta_star) and delta_star <= delta)


def bootstrap_ci(values: list[float], level: float = 0.95, resamples: int = 10_000,
                 seed: int = 0) -> list[float] | None:
    """Percentile bootstrap interval of the mean (seeded: the same runs, the same interval);
    None for fewer than two finite values."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if len(x) < 2:
        return None
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, len(x), size=(resamples, len(x)))].mean(axis=1)
    tail = (1.0 - level) / 2
    return [float(np.quantile(means, tail)), float(np.quantile(means, 1.0 - tail))]


def wilson_ci(successes: int, runs: int, level: float = 0.95) -> list[float] | None:
    """Wilson score interval of a success fraction (None for no runs)."""
    if runs <= 0:
        return None
    from scipy.stats import binomtest
    ci = binomtest(successes, runs).proportion_ci(confidence_level=level, method='wilson')
    return [float(ci.low), float(ci.high)]


def returned_summary(finals: list[dict]) -> dict:
    """The returned policies' own episodes over the runs: value and delta* (mean, std, 95 %
    bootstrap interval), the runs whose policy reaches S_delta (with a Wilson interval), the
    runs whose policy touches the rail and the mean number of contacts."""
    out = {}
    for key in ('policy_value', 'policy_delta_star'):
        values = [f[key] for f in finals]
        mean, std = _mean_std(values)
        out.update({f'{key}_mean': mean, f'{key}_std': std, f'{key}_ci95': bootstrap_ci(values)})
    reached = sum(bool(f['policy_reached']) for f in finals)
    contacts = [f['policy_rail_contacts'] for f in finals]
    return {**out, 'policy_reached': reached, 'policy_reached_ci95': wilson_ci(reached,
                                                                               len(finals)),
            'policy_rail_runs': sum(c > 0 for c in contacts),
            'policy_rail_contacts_mean': float(np.mean(contacts))}


def count_text(count: int, runs: int, final: dict, key: str = 'achieved') -> str:
    """'k/n [low, high]' with the Wilson interval of ``final[key + '_ci95']``."""
    ci = final.get(f'{key}_ci95')
    return f'{count}/{runs}' + (f' [{ci[0]:.2f}, {ci[1]:.2f}]' if ci else '')


def returned_text(final: dict) -> str:
    """The returned policies' own measures for a table cell ('n/a' for runs that predate
    them)."""
    if 'policy_value_mean' not in final:
        return 'n/a'
    return (f'{_value_text(final)}, '
            f"{final['policy_delta_star_mean']:.4f} ± {final['policy_delta_star_std']:.4f}, "
            f"{count_text(final['policy_reached'], final['runs'], final, 'policy_reached')}, "
            f"{final['policy_rail_contacts_mean']:.1f} (in {final['policy_rail_runs']} runs)")


def hold_summary(finals: list[dict]) -> dict:
    """The hold task's measures over the runs: hold fraction (mean, std, 95 % interval),
    runs holding >= 0.95, runs holding >= 0.9 with no rail contact, first entry step (mean
    over the runs that entered), rail contacts (mean)."""
    hold = [f['hold_fraction'] for f in finals]
    entered = [f['first_entry_step'] for f in finals if f['first_entry_step'] is not None]
    return {'hold_fraction_mean': float(np.mean(hold)), 'hold_fraction_std': float(np.std(hold)),
            'hold_fraction_ci95': bootstrap_ci(hold),
            'holding': int(sum(h >= 0.95 for h in hold)),
            'holding_clean': int(sum(f['hold_fraction'] >= 0.9 and f['rail_contacts'] == 0
                                     for f in finals)),
            'first_entry_mean': float(np.mean(entered)) if entered else None,
            'rail_contacts_mean': float(np.mean([f['rail_contacts'] for f in finals]))}


def _value_text(final: dict) -> str:
    """The returned policies' value, mean ± std ('n/a' for runs that predate it)."""
    if final.get('policy_value_mean') is None:
        return 'n/a'
    return f"{final['policy_value_mean']:.1f} ± {final['policy_value_std']:.1f}"


def markdown_table(summaries: list[dict]) -> str:
    """The final measures of each experiment as a Markdown table."""
    lines = ['| # | problem | delta | method | style | steps | achieved [95 % CI] | '
             'run best value | run delta* | returned policy: value, delta*, reaches, '
             'rail contacts | steps/s (one run) |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for s in summaries:
        f = s['final']
        style = s.get('style', 'state-action') if s['method'] == 'sapga' else '-'
        lines.append(f"| {s['id']} | {s['problem']} | {s['delta']} | {s['method']} | {style} "
                     f"| {s['steps']:,d} | {count_text(f['achieved'], f['runs'], f)} "
                     f"| {f['best_value_mean']:.1f} ± {f['best_value_std']:.1f} "
                     f"| {f['delta_star_mean']:.4f} ± {f['delta_star_std']:.4f} "
                     f'| {returned_text(f)} '
                     f"| {s.get('timing', {}).get('steps_per_s_mean', math.nan) / 1e3:,.0f} k |")
    lines += hold_table(summaries)
    return '\n'.join(lines) + '\n'


def row_method(s: dict) -> str:
    """A row's method as the tables and figures name it: the method, its variant, the LQR
    catch, the disturbance of its robust fitness."""
    text = s['method']
    if s.get('variant', 'paper') != 'paper':
        text += f" [{s['variant']}]"
    return text + row_controls(s)


def row_controls(s: dict) -> str:
    """What a row's policies run behind and were trained against, as words after its
    method: the LQR catch, the delay the selector is designed for, robust fitness."""
    text = ''
    if s.get('catch', 'none') != 'none':
        text += ' + LQR catch'
        if s.get('catch_delay'):
            text += f" (delay {s['catch_delay']})"
    if s.get('delay'):
        text += f" acting {s['delay']} step{'s' if s['delay'] > 1 else ''} ahead"
    if s.get('disturbance', 'none') != 'none':
        redrawn = ', drawn each generation' if s.get('redraw') else ''
        text += f" robust ({s['disturbance']}, K = {s.get('episodes', 1)}{redrawn})"
    return text


def hold_table(summaries: list[dict]) -> list[str]:
    """The hold measures of the rows that have them, as Markdown lines (none: []): each
    seed's returned policy on its own episode, and that episode's value (the fitness)."""
    held = [s for s in summaries if 'holding' in s['final']]
    if not held:
        return []
    lines = ['', '| # | problem | method | hold fraction | 95 % interval | >= 0.95 | '
             '>= 0.9, no rail contact | first entry step | rail contacts | value |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for s in held:
        f = s['final']
        ci = f['hold_fraction_ci95']
        ci = '-' if ci is None else f'[{ci[0]:.3f}, {ci[1]:.3f}]'
        first = '-' if f['first_entry_mean'] is None else f"{f['first_entry_mean']:.0f}"
        lines.append(f"| {s['id']} | {s['problem']} | {row_method(s)} "
                     f"| {f['hold_fraction_mean']:.3f} ± {f['hold_fraction_std']:.3f} "
                     f"| {ci} | {f['holding']}/{f['runs']} "
                     f"| {f['holding_clean']}/{f['runs']} | {first} "
                     f"| {f['rail_contacts_mean']:.2f} | {_value_text(f)} |")
    return lines
