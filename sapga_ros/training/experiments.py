"""The paper's experiments (Table 2; SPEC 3.5): many seeds, measures against steps.

For each experiment and seed a run is trained (SAP-GA or Q-learning); its log gives, at
every step count, the best evaluated value so far, delta* so far and whether delta was
achieved.  The curves are resampled on a common grid of steps, averaged over seeds (mean
and standard deviation), written to ``summary.json`` and drawn like the paper's Figures 3
and 4.  Runs go to worker processes (one evaluation thread each).
"""
from __future__ import annotations

import json
import math
import os
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from sapga_ros.errors import ConfigError
from sapga_ros.exemplars.styles import STYLES
from sim_nodes.problem import config_dir, load_problem

GRID_POINTS = 100


@dataclass(frozen=True)
class Experiment:
    id: int
    problem: str
    delta: float
    method: str
    steps: int
    style: str = 'state-action'            # exemplar style of a SAP-GA experiment


def load_experiments(name: str) -> tuple[list[Experiment], int]:
    """Experiments and seed count of msg_configs/experiments/<name>.yaml."""
    path = config_dir() / 'experiments' / f'{name}.yaml'
    if not path.is_file():
        known = sorted(p.stem for p in (config_dir() / 'experiments').glob('*.yaml'))
        raise ConfigError(f'unknown experiment set {name!r} (known: {", ".join(known)})')
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
        exps = [Experiment(int(e['id']), str(e['problem']), float(e['delta']),
                           str(e['method']), int(e['steps']), str(e.get('style', 'state-action')))
                for e in doc['experiments']]
        seeds = int(doc.get('seeds', 20))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f'{path}: malformed experiment file ({exc})') from exc
    for e in exps:
        load_problem(e.problem)
        if e.method not in ('sapga', 'ql') or e.steps <= 0 or not e.delta >= 0:
            raise ConfigError(f'{path}: experiment {e.id}: bad method/steps/delta')
        if e.style not in STYLES:
            raise ConfigError(f'{path}: experiment {e.id}: unknown style {e.style[:40]!r} '
                              f'(known: {", ".join(STYLES)})')
    return exps, seeds


def _run_one(args: tuple) -> dict:
    exp, seed, steps = args
    from sapga_ros.training.ql_run import train_ql
    from sapga_ros.optim.sapga import SapgaParams
    from sapga_ros.training.loop import TrainConfig, train_sapga
    cfg = TrainConfig(problem=exp.problem, method=exp.method, delta=exp.delta, steps=steps,
                      seed=seed, jobs=1, params=SapgaParams(style=exp.style))
    result = train_sapga(cfg) if exp.method == 'sapga' else train_ql(cfg)
    hist = result.history
    return {'seed': seed, 'steps': [r['steps'] for r in hist],
            'best_value': [r['best_value'] for r in hist],
            'delta_star': [r['delta_star'] for r in hist],
            'final': {'best_value': hist[-1]['best_value'],
                      'delta_star': hist[-1]['delta_star'],
                      'achieved': hist[-1]['delta_star'] <= exp.delta,
                      'steps_per_s': hist[-1]['steps_per_s']}}


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
    return {'id': exp.id, 'problem': exp.problem, 'method': exp.method, 'delta': exp.delta,
            'style': exp.style,
            'steps': budget, 'seeds': [r['seed'] for r in runs], 'grid': grid.tolist(),
            'best_value': stat(best), 'delta_star': stat(dstar),
            'achieved_fraction': achieved.mean(axis=0).tolist(),
            'final': {'best_value_mean': float(np.mean([f['best_value'] for f in finals])),
                      'best_value_std': float(np.std([f['best_value'] for f in finals])),
                      'delta_star_mean': float(np.mean([f['delta_star'] for f in finals])),
                      'delta_star_std': float(np.std([f['delta_star'] for f in finals])),
                      'achieved': int(sum(f['achieved'] for f in finals)),
                      'steps_per_s_mean': float(np.mean([f.get('steps_per_s', math.nan)
                                                         for f in finals])),
                      'runs': len(finals)}}


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
                     f"| {f.get('steps_per_s_mean', math.nan) / 1e3:,.0f} k |")
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


def run_experiments(name: str, out: str | os.PathLike, only: list[int] | None = None,
                    seeds: int | None = None, scale: float = 1.0,
                    workers: int | None = None, log=print) -> list[dict]:
    """Run (a part of) an experiment set; write summary.json, runs.json and figures."""
    exps, default_seeds = load_experiments(name)
    if only:
        unknown = set(only) - {e.id for e in exps}
        if unknown:
            raise ConfigError(f'no experiment {sorted(unknown)} in {name}')
        exps = [e for e in exps if e.id in only]
    n_seeds = default_seeds if seeds is None else seeds
    if not scale > 0 or not math.isfinite(scale):
        raise ConfigError(f'--scale must be a positive number, got {scale}')
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    workers = workers or os.cpu_count() or 1
    summaries, raw = [], {}
    for exp in exps:
        budget = max(1000, int(exp.steps * scale))
        log(f'experiment #{exp.id}: {exp.method} on {exp.problem}, delta {exp.delta}, '
            f'{budget:,d} steps x {n_seeds} seeds')
        jobs = [(exp, seed, budget) for seed in range(n_seeds)]
        if workers == 1:
            runs = [_run_one(j) for j in jobs]
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                runs = list(pool.map(_run_one, jobs))
        s = summarise(exp, runs, budget)
        f = s['final']
        log(f"  achieved {f['achieved']}/{f['runs']}, best value {f['best_value_mean']:.1f} "
            f"+- {f['best_value_std']:.1f}, delta* {f['delta_star_mean']:.4f} "
            f"+- {f['delta_star_std']:.4f}")
        summaries.append(s)
        raw[str(exp.id)] = runs
    (out / 'summary.json').write_text(json.dumps(summaries, indent=1))
    (out / 'summary.md').write_text(markdown_table(summaries))
    (out / 'runs.json').write_text(json.dumps(raw))
    for path in plot_summaries(summaries, out):
        log(f'figure: {path}')
    return summaries
