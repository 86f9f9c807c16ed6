"""Summaries of an experiment's runs: curves against steps averaged over seeds,
the final measures, a Markdown table and the figures drawn like the paper's Figures 3 and 4.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

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


def summarise(exp: Experiment, runs: list[dict], budget: int) -> dict:
    grid = np.linspace(budget / GRID_POINTS, budget, GRID_POINTS)
    best = np.array([resample(r['steps'], r['best_value'], grid) for r in runs])
    dstar = np.array([resample(r['steps'], r['delta_star'], grid) for r in runs])
    dstar = np.where(np.isfinite(dstar), dstar, np.nan)
    achieved = (dstar <= exp.delta).astype(float)

    def stat(a):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # all-nan columns: no run yet
            return {'mean': _nulls(np.nanmean(a, axis=0)), 'std': _nulls(np.nanstd(a, axis=0))}
    finals = [r['final'] for r in runs]
    final = {'best_value_mean': float(np.mean([f['best_value'] for f in finals])),
             'best_value_std': float(np.std([f['best_value'] for f in finals])),
             'delta_star_mean': float(np.mean([f['delta_star'] for f in finals])),
             'delta_star_std': float(np.std([f['delta_star'] for f in finals])),
             'achieved': int(sum(f['achieved'] for f in finals)),
             'runs': len(finals),
             'best_value_ci95': bootstrap_ci([f['best_value'] for f in finals]),
             'delta_star_ci95': bootstrap_ci([f['delta_star'] for f in finals])}
    for key in ('delta_star_alt', 'greedy_delta_star'):
        values = [f[key] for f in finals if f.get(key) is not None]
        if len(values) == len(finals):
            final.update({f'{key}_mean': float(np.mean(values)),
                          f'{key}_std': float(np.std(values)),
                          f'{key}_ci95': bootstrap_ci(values)})
            if key == 'delta_star_alt':
                final['achieved_alt'] = int(sum(v <= exp.delta for v in values))
    return {'id': exp.id, 'problem': exp.problem, 'method': exp.method, 'delta': exp.delta,
            'style': exp.style, 'variant': exp.variant, 'paper': exp.paper,
            'group': exp.group,
            'steps': budget, 'seeds': [r['seed'] for r in runs], 'grid': grid.tolist(),
            'best_value': stat(best), 'delta_star': stat(dstar),
            'achieved_fraction': achieved.mean(axis=0).tolist(), 'final': final,
            # wall-clock speed of the runs: the one measure that differs between machines
            'timing': {'steps_per_s_mean': float(np.mean([f.get('steps_per_s', math.nan)
                                                          for f in finals])),
                       'seconds_total': float(sum(r.get('seconds', math.nan)
                                                  for r in runs))}}


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


def markdown_table(summaries: list[dict]) -> str:
    """The final measures of each experiment as a Markdown table."""
    lines = ['| # | problem | delta | method | style | steps | achieved | best value | '
             'delta* | steps/s (one run) |', '|---|---|---|---|---|---|---|---|---|---|']
    for s in summaries:
        f = s['final']
        style = s.get('style', 'state-action') if s['method'] == 'sapga' else '-'
        lines.append(f"| {s['id']} | {s['problem']} | {s['delta']} | {s['method']} | {style} "
                     f"| {s['steps']:,d} | {f['achieved']}/{f['runs']} "
                     f"| {f['best_value_mean']:.1f} ± {f['best_value_std']:.1f} "
                     f"| {f['delta_star_mean']:.4f} ± {f['delta_star_std']:.4f} "
                     f"| {s.get('timing', {}).get('steps_per_s_mean', math.nan) / 1e3:,.0f} k |")
    return '\n'.join(lines) + '\n'


def plot_summaries(summaries: list[dict], out: Path) -> list[Path]:
    """One figure per problem: best value, delta* and achieved fraction against steps."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    paths = []
    groups: dict[str, list[dict]] = {}
    for s in summaries:
        groups.setdefault(s['problem'].split('_')[0], []).append(s)
    for family, items in groups.items():
        fig, axes = plt.subplots(1, 3, figsize=(14, 4))
        for s in items:
            x = np.array(s['grid']) / 1e6
            style = s.get('style', 'state-action')
            label = (f"#{s['id']} {s['method'].upper()} {s['problem']} delta={s['delta']}"
                     + (f' {style}' if style != 'state-action' else ''))
            for ax, key in zip(axes[:2], ('best_value', 'delta_star')):
                m = np.array(s[key]['mean'], dtype=float)
                sd = np.array(s[key]['std'], dtype=float)
                ax.plot(x, m, label=label)
                ax.fill_between(x, m - sd, m + sd, alpha=0.2)
            axes[2].plot(x, s['achieved_fraction'], label=label)
        axes[0].set_ylabel('best evaluated value')
        axes[1].set_ylabel('delta* so far')
        if any(v is not None and v > 0 for s in items for v in s['delta_star']['mean']):
            axes[1].set_yscale('log')
        axes[2].set_ylabel('fraction of runs that achieved delta')
        for ax in axes:
            ax.set_xlabel('total steps [millions]')
        axes[0].legend(fontsize=7)
        fig.suptitle(f'{family}: mean and standard deviation over seeds')
        fig.tight_layout()
        path = out / f'{family}.png'
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths
