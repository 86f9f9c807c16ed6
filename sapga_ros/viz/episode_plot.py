"""Plots of a recorded episode (``sapga inspect --plot``), like the paper's Figures 6 and 7:
angles, positions, velocities and the command over time, and a stroboscopic picture of the
pendulum drawn by ``sim_nodes.geometry`` (acrobot: two links from the shoulder; PDIP: the
cart and its two poles; pendulum; mountain car on its hill).

The goal is marked: each coordinate's best value as a dashed green line inside its S_delta
band (shaded, at the recording's goal delta), and the best state's picture in the
stroboscope.  Angles live on the circle [0, 2pi): where one wraps (a step of more than pi)
its line is broken (``break_wraps``), so a turn over the top draws no vertical jump.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from sapga_ros.io.atomic import save_figure_file
from sapga_ros.recording.episodes import Episode
from sapga_ros.viz.quiet import quiet_drawing
from sim_nodes.geometry import drawing, goal_band, goal_states, picture, track

GOAL_COLOR = 'tab:green'


def break_wraps(t: np.ndarray, y: np.ndarray, period: float = 2 * math.pi
                ) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) with a NaN sample inserted between neighbours whose values differ by more
    than half the period: a wrapped angle then plots without a vertical jump."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    cuts = np.flatnonzero(np.abs(np.diff(y)) > period / 2) + 1
    if not len(cuts):
        return t, y
    mid = (t[cuts - 1] + t[cuts]) / 2
    return np.insert(t, cuts, mid), np.insert(y, cuts, np.nan)


def _goal_spans(best: float, half: float, angle: bool) -> list[tuple[float, float]]:
    """The band best +- half as spans of the plotted axis (angles: within [0, 2pi))."""
    if not angle:
        return [(best - half, best + half)]
    if half >= math.pi:
        return [(0.0, 2 * math.pi)]
    lo, hi = (best - half) % (2 * math.pi), (best + half) % (2 * math.pi)
    return [(lo, hi)] if lo <= hi else [(0.0, hi), (lo, 2 * math.pi)]


def _mark_goal(ax: Any, problem: Any, idx: list[int], half: np.ndarray | None) -> None:
    best = problem.best_state
    for n, i in enumerate(idx):
        label = 'goal' if n == 0 else None
        ax.axhline(best[i], color=GOAL_COLOR, ls='--', lw=1, label=label)
        if half is not None and 0 < half[i] < math.inf:
            for lo, hi in _goal_spans(best[i], half[i], problem.state[i].angle):
                ax.axhspan(lo, hi, color=GOAL_COLOR, alpha=0.12, lw=0)


def episode_figure(ep: Episode, problem: Any, title: str,
                   goal_delta: float | None = None) -> Any:
    """The figure of ``plot_episode`` (matplotlib, Agg), not yet saved."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    stamps, x = ep.trajectory()
    t = (stamps - stamps[0]) * 1e-9
    coords = list(problem.state)
    half = goal_band(problem, goal_delta) if goal_delta is not None else None
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
            ti, yi = break_wraps(t, x[:, i]) if coords[i].angle else (t, x[:, i])
            ax.plot(ti, yi, label=f'{coords[i].name} [{coords[i].unit}]')
        _mark_goal(ax, problem, idx, half)
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
    draw_strobe(strobe, problem, x, goal_delta)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


@quiet_drawing()
def plot_episode(ep: Episode, problem: Any, out_path: str, title: str,
                 goal_delta: float | None = None) -> None:
    """Angles, velocities, command over time and a stroboscopic picture, to a PNG file;
    the goal marked (its band at ``goal_delta`` when given)."""
    import matplotlib.pyplot as plt

    fig = episode_figure(ep, problem, title, goal_delta)
    try:
        save_figure_file(fig, out_path, dpi=100)
    finally:
        plt.close(fig)


def _draw_picture(ax: Any, problem: Any, s: np.ndarray, color: Any, alpha: float,
                  lw: float = 2.0, ls: str = '-') -> None:
    from matplotlib.patches import Rectangle

    pic = picture(problem, s)
    width, height = drawing(problem).body_size
    for (x0, z0), (x1, z1) in pic.links:
        ax.plot([x0, x1], [z0, z1], ls=ls, color=color, alpha=alpha, lw=lw)
    if pic.joints:
        ax.plot(*zip(*pic.joints), 'o', color=color, alpha=alpha, ms=3)
    if pic.body is not None:
        bx, bz = pic.body
        ax.add_patch(Rectangle((bx - width / 2, bz - height / 2), width, height, fill=False,
                               color=color, alpha=alpha))


def draw_strobe(ax: Any, problem: Any, x: np.ndarray, goal_delta: float | None) -> None:
    """A stroboscopic picture of the states ``x`` (rows) with the goal pose, on ``ax``."""
    from matplotlib import colormaps

    if drawing(problem) is None:
        ax.text(0.5, 0.5, f'no picture for model {problem.model!r}',
                transform=ax.transAxes, ha='center')
        return
    rail = track(problem)
    if rail:
        ax.plot(*zip(*rail), color='0.5', lw=1)
    for k, s in enumerate(goal_states(problem, goal_delta or 0.0)):
        _draw_picture(ax, problem, s, GOAL_COLOR, 0.8 if k == 0 else 0.4,
                      lw=3 if k == 0 else 1, ls='--')
    frames = np.unique(np.linspace(0, len(x) - 1, min(len(x), 30)).astype(int))
    cmap = colormaps['viridis']
    for k, i in enumerate(frames):
        share = k / max(len(frames) - 1, 1)
        _draw_picture(ax, problem, x[i], cmap(share), 0.25 + 0.75 * share)
    ax.set_aspect('equal')
    ax.set_title(f'{len(frames)} frames, purple (start) to yellow (end); goal green',
                 fontsize='small')
    ax.grid(alpha=0.3)
