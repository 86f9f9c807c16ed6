"""The figures of an experiment's summaries, drawn like the paper's Figures 3 and 4: best
value, delta* and the fraction of runs that achieved delta against steps, one figure per
problem family (the summaries are ``sapga_ros.training.experiment_report.summarise``'s).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sapga_ros.viz.quiet import quiet_drawing


@quiet_drawing()
def plot_summaries(summaries: list[dict], out: Path) -> list[Path]:
    """One figure per problem: best value, delta* and achieved fraction against steps."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from sapga_ros.io.atomic import save_figure
    from sapga_ros.training.experiment_report import row_method
    paths = []
    groups: dict[str, list[dict]] = {}
    for s in summaries:
        groups.setdefault(s['problem'].split('_')[0], []).append(s)
    for family, items in groups.items():
        fig, axes = plt.subplots(1, 3, figsize=(14, 4))
        for s in items:
            x = np.array(s['grid']) / 1e6
            style = s.get('style', 'state-action')
            method = s['method'].upper() + row_method(s)[len(s['method']):]   # + variant
            label = (f"#{s['id']} {method} {s['problem']} delta={s['delta']}"
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
        path = save_figure(fig, out, f'{family}.png')
        plt.close(fig)
        paths.append(path)
    return paths
