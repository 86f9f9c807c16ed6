"""Plots of a recorded episode (``sapga inspect --plot``), like the paper's Figures 6 and 7:
angles, velocities and the command over time, and a stroboscopic picture of the pendulum
(acrobot: two links from the shoulder; PDIP: the cart and its two poles).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from sapga_ros.recording.episodes import Episode


def plot_episode(ep: Episode, problem: Any, out_path: str, title: str) -> None:
    """Angles, velocities, command over time and a stroboscopic picture, to a PNG file."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    stamps, x = ep.trajectory()
    t = (stamps - stamps[0]) * 1e-9
    coords = list(problem.state)
    groups = [('angle [rad]', [i for i, c in enumerate(coords) if c.angle]),
              ('position [m]', [i for i, c in enumerate(coords)
                                if not c.angle and c.field == 'position']),
              ('velocity', [i for i, c in enumerate(coords) if c.field == 'velocity'])]
    groups = [g for g in groups if g[1]]
    rows = len(groups) + 1
    fig = plt.figure(figsize=(12, 2.2 * rows + 0.6))
    grid = fig.add_gridspec(rows, 2, width_ratios=[1.6, 1.0])
    ax = None
    for r, (label, idx) in enumerate(groups):
        ax = fig.add_subplot(grid[r, 0], sharex=ax)
        for i in idx:
            ax.plot(t, x[:, i], label=f'{coords[i].name} [{coords[i].unit}]')
        ax.set_ylabel(label)
        ax.legend(loc='upper right', fontsize='small')
        ax.grid(alpha=0.3)
    ax = fig.add_subplot(grid[rows - 1, 0], sharex=ax)
    if ep.commands:
        ct = [((stamp if stamp is not None else stamps[0]) - stamps[0]) * 1e-9
              for stamp, _ in ep.commands]
        ax.step(ct, [u for _, u in ep.commands], where='post', color='k')
    ax.set_ylabel('command')
    ax.set_xlabel('time [s]')
    ax.grid(alpha=0.3)
    strobe = fig.add_subplot(grid[:, 1])
    _draw_strobe(strobe, problem, x)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out_path, dpi=100)
    plt.close(fig)


def _draw_strobe(ax: Any, problem: Any, x: np.ndarray) -> None:
    from matplotlib import colormaps
    from matplotlib.patches import Rectangle

    names = list(problem.state_names)
    ph = problem.physics
    frames = np.unique(np.linspace(0, len(x) - 1, min(len(x), 30)).astype(int))
    cmap = colormaps['viridis']
    for k, i in enumerate(frames):
        color = cmap(k / max(len(frames) - 1, 1))
        alpha = 0.25 + 0.75 * k / max(len(frames) - 1, 1)
        s = dict(zip(names, x[i]))
        if problem.model == 'acrobot':
            l1, l2 = ph.get('l1', 1.0), ph.get('l2', ph.get('l1', 1.0))
            th1, th2 = s['theta1'], s['theta1'] + s['theta2']
            px = [0.0, l1 * math.cos(th1), l1 * math.cos(th1) + l2 * math.cos(th2)]
            py = [0.0, l1 * math.sin(th1), l1 * math.sin(th1) + l2 * math.sin(th2)]
            ax.plot(px, py, '-o', color=color, alpha=alpha, lw=2, ms=3)
        elif problem.model == 'pdip':
            cx = s.get('x', 0.0)
            ax.add_patch(Rectangle((cx - 0.2, -0.1), 0.4, 0.2, fill=False, color=color,
                                   alpha=alpha))
            for pole, length, lw in (('theta1', ph.get('l1', 1.0), 2.5),
                                     ('theta2', ph.get('l2', 0.5), 1.2)):
                if pole in s:
                    ax.plot([cx, cx + length * math.cos(s[pole])],
                            [0.0, length * math.sin(s[pole])], '-', color=color,
                            alpha=alpha, lw=lw)
        else:
            ax.text(0.5, 0.5, f'no picture for model {problem.model!r}',
                    transform=ax.transAxes, ha='center')
            return
    if problem.model == 'pdip':
        xm = ph.get('x_max', 2.5)
        ax.plot([-xm, xm], [0, 0], color='0.5', lw=1)
    ax.set_aspect('equal')
    ax.set_title(f'{len(frames)} frames, purple (start) to yellow (end)', fontsize='small')
    ax.grid(alpha=0.3)
