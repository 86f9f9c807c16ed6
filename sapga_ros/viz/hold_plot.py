"""The hold task's figures in an experiment report: the hold fraction of every seed's
returned policy per row, and a whole episode (50 s on acrobot_hold and pdip_hold) of each
row's best returned policy: its distance to the goal, delta(s), against time, with the
row's delta (S_delta is below the line).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sapga_ros.errors import DataFileError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.io.atomic import save_figure
from sapga_ros.policies.runnable import policy_from_document
from sapga_ros.training.experiment_report import row_method
from sapga_ros.training.run_files import run_path, stored_runs
from sapga_ros.viz.quiet import quiet_drawing
from sim_nodes.goal import delta_of


def _label(s: dict) -> str:
    return f"#{s['id']} {row_method(s)}"


def _runs(out: Path, s: dict) -> tuple[list[tuple[int, dict]], tuple | None]:
    """(seed, final measures) of each of the row's stored runs, and (seed, policy document)
    of the best (hold fraction, then value; only that policy is kept in memory).  A run
    file of the row without the hold measures is refused, naming the file."""
    rows, best, best_key = [], None, None
    for seed, run in stored_runs(out, s['id'], s['seeds']):
        f = run['final']
        if 'hold_fraction' not in f:
            raise DataFileError(f"{run_path(out, s['id'], seed)}: run.final: missing field "
                                f"'hold_fraction' (summary row #{s['id']} has hold measures)")
        rows.append((seed, f))
        key = (f['hold_fraction'], f.get('policy_value', -math.inf))
        if run.get('policy') is not None and (best_key is None or key > best_key):
            best, best_key = (seed, run['policy']), key
    return rows, best


@quiet_drawing()
def hold_figures(out: Path, summaries: list[dict]) -> list[str]:
    """The two figures for the rows with hold measures; the report's lines."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    rows = [s for s in summaries if 'holding' in s['final']]
    if not rows:
        return []
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(rows)), 4))
    best = []
    for i, s in enumerate(rows):
        runs, top = _runs(out, s)
        hold = np.array([f['hold_fraction'] for _, f in runs])
        jitter = np.linspace(-0.25, 0.25, len(hold)) if len(hold) > 1 else np.zeros(len(hold))
        ax.scatter(i + jitter, hold, s=14, alpha=0.7)
        best.append((s, top))
    ax.axhline(0.95, color='tab:green', ls='--', lw=1, label='0.95')
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels([f"{_label(s)}\n{s['problem']}" for s in rows], fontsize='x-small')
    ax.set_ylabel('hold fraction of the returned policy')
    ax.set_ylim(-0.03, 1.03)
    ax.set_title('every seed\'s returned policy (one dot each)', fontsize='small')
    ax.legend(fontsize='small')
    fig.tight_layout()
    per_seed = save_figure(fig, out, 'hold_fraction.png')
    plt.close(fig)
    fig, axes = plt.subplots(len(rows), 1, figsize=(9, 1.9 * len(rows)), squeeze=False)
    titles = []
    for ax, (s, top) in zip(axes[:, 0], best):
        if top is None:
            ax.set_title(f'{_label(s)}: no stored policy', fontsize='small')
            continue
        seed, doc = top
        policy = policy_from_document(doc, s['problem'],
                                      f"{run_path(out, s['id'], seed)}: run.policy")
        ep = Evaluator(policy.problem, s['delta']).episode(policy)
        pr = policy.problem
        t = np.arange(len(ep.states)) * pr.dt * pr.substeps
        d = np.array([delta_of(pr, x) for x in ep.states])
        ax.semilogy(t, np.maximum(d, 1e-6), lw=1)
        ax.axhline(s['delta'], color='tab:green', ls='--', lw=1)
        m = ep.summary()
        title = (f"{_label(s)} on {s['problem']}, seed {seed}: first entry "
                 f"{m['first_entry_step'] if m['first_entry_step'] is not None else 'none'}, "
                 f"hold fraction {m['hold_fraction']:.3f}, rail contacts {m['rail_contacts']}")
        ax.set_title(title, fontsize='x-small')
        ax.set_ylabel('δ(s)')
        titles.append(title)
    axes[-1, 0].set_xlabel('time [s]')
    fig.tight_layout()
    episodes = save_figure(fig, out, 'hold_episodes.png')
    plt.close(fig)
    return ['**Hold fraction per seed** (each row\'s returned policies):', '',
            f'![hold fraction]({per_seed.name})', '',
            '**A whole episode of each row\'s best returned policy** (by hold fraction, then '
            'value): δ(s) against time, the row\'s δ dashed (S_δ below it).', '',
            f'![hold episodes]({episodes.name})', '']
