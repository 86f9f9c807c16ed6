"""Success-rate curves against a disturbance's size: one figure per profile, one curve per
policy (``sapga robustness``) or per experiment row (the experiment report, with the 95 %
interval over the row's seeds as a band)."""
from __future__ import annotations

import re
from pathlib import Path

from sapga_ros.viz.quiet import quiet_drawing


@quiet_drawing()
def curve_figures(curves: dict[str, dict[str, list[tuple]]], out: Path, prefix: str,
                  ylabel: str, note: str) -> list[Path]:
    """``curves[profile][label]`` = [(scale, rate, (low, high) or None), ...]; one figure
    ``out/<prefix><profile>.png`` per profile; ``note`` ends each title."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from sapga_ros.io.atomic import save_figure
    paths = []
    for profile, lines in curves.items():
        fig, ax = plt.subplots(figsize=(6, 4))
        for label, points in lines.items():
            x = [p[0] for p in points]
            drawn = ax.plot(x, [p[1] for p in points], 'o-', label=label)
            band = [p[2] for p in points]
            if all(b is not None for b in band) and band:
                ax.fill_between(x, [b[0] for b in band], [b[1] for b in band],
                                color=drawn[0].get_color(), alpha=0.15)
        ax.set_xlabel(f'size x the {profile} profile')
        ax.set_ylabel(ylabel)
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(f'{profile}: {note}', fontsize='small')
        ax.grid(alpha=0.3)
        ax.legend(fontsize='small')
        fig.tight_layout()
        name = re.sub(r'[^A-Za-z0-9_-]', '_', f'{prefix}{profile}') + '.png'
        paths.append(save_figure(fig, out, name))
        plt.close(fig)
    return paths
