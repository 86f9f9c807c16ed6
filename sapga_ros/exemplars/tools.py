"""Looking at a policy's exemplars: a table with referral counts, and a picture.

The picture shows, for each (angle, angular velocity) pair of the state, the exemplars as
markers coloured by action (size by how often the episode referred to them) with the
episode's trajectory on top: knowledge extraction after optimisation (paper section 2).
"""
from __future__ import annotations

import numpy as np

from sapga_ros.exemplars.policy import ExemplarPolicy


def exemplar_table(policy: ExemplarPolicy, counts: np.ndarray) -> list[dict]:
    values = policy.action_values
    return [{'index': j, 'uses': int(counts[j]), 'action': float(values[j]),
             'state': [float(x) for x in policy.states[j]]} for j in range(len(policy))]


def _pairs(problem) -> list[tuple[int, int]]:
    """(position, velocity) coordinate pairs that belong to the same joint."""
    coords = problem.state
    pairs = []
    for i, c in enumerate(coords):
        if c.field == 'position':
            for j, d in enumerate(coords):
                if d.field == 'velocity' and d.joint == c.joint:
                    pairs.append((i, j))
    return pairs


def _break_wraps(x: np.ndarray, y: np.ndarray, angle: bool):
    """Insert gaps where an angle wraps round, so no line crosses the picture."""
    if not angle or len(x) < 2:
        return x, y
    cut = np.flatnonzero(np.abs(np.diff(x)) > np.pi) + 1
    return np.insert(x.astype(float), cut, np.nan), np.insert(y.astype(float), cut, np.nan)


def policy_map(policy: ExemplarPolicy, resolution: int = 200):
    """Action chosen over a grid of a 2-D problem's state space: (xs, ys, action values)."""
    from sapga_ros.exemplars.distance import nearest, normalize_into, normalize_states
    problem = policy.problem
    xs = np.linspace(problem.low[0], problem.high[0], resolution)
    ys = np.linspace(problem.low[1], problem.high[1], resolution)
    ex = normalize_states(policy.states, problem.ranges, problem.is_angle)
    inv, ang = 1.0 / problem.ranges, problem.is_angle
    u, acc = np.empty(2), np.empty(len(policy))
    values = policy.action_values
    grid = np.empty((resolution, resolution))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            normalize_into(np.array([x, y]), inv, ang, u)
            grid[i, j] = values[nearest(u, ex, len(policy), ang, acc)]
    return xs, ys, grid


def plot_exemplars(policy: ExemplarPolicy, episode, counts: np.ndarray, out: str) -> None:
    """Exemplars and trajectory per (angle, velocity) pair; for a 2-D problem the policy
    map of the paper's Figure 5 (the action taken everywhere, exemplars, trajectory)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    problem = policy.problem
    if problem.dim == 2:
        xs, ys, grid = policy_map(policy)
        fig, ax = plt.subplots(figsize=(6, 5))
        ax.pcolormesh(xs, ys, grid, cmap='Greys', shading='auto', alpha=0.6)
        values = policy.action_values
        for a, marker in zip(problem.actions, ('s', '^', 'o')):
            sel = values == a
            ax.scatter(policy.states[sel, 0], policy.states[sel, 1], marker=marker,
                       facecolors='none', edgecolors='k', label=f'exemplar, action {a:g}')
        ax.plot(episode.states[:, 0], episode.states[:, 1], 'r-', lw=1, label='trajectory')
        ax.set_xlabel(f'{problem.state[0].name} [{problem.state[0].unit}]')
        ax.set_ylabel(f'{problem.state[1].name} [{problem.state[1].unit}]')
        ax.legend(fontsize=7, loc='lower left')
        ax.set_title(f'{problem.name}: action {max(problem.actions):g} in dark areas; '
                     f'{episode.steps} steps')
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
        return
    pairs = _pairs(problem)
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.5 * len(pairs), 4), squeeze=False)
    values = policy.action_values
    colours = {a: c for a, c in zip(problem.actions, ('tab:blue', 'tab:grey', 'tab:red'))}
    for ax, (i, j) in zip(axes[0], pairs):
        for a in problem.actions:
            sel = values == a
            ax.scatter(policy.states[sel, i], policy.states[sel, j],
                       s=12 + 3 * np.sqrt(counts[sel]), c=colours.get(a, 'k'),
                       label=f'action {a:g}', alpha=0.8, edgecolors='none')
        xs, ys = _break_wraps(episode.states[:, i], episode.states[:, j],
                              problem.state[i].angle)
        ax.plot(xs, ys, 'k-', lw=0.6, alpha=0.6, label='trajectory')
        ax.set_xlabel(f'{problem.state[i].name} [{problem.state[i].unit}]')
        ax.set_ylabel(f'{problem.state[j].name} [{problem.state[j].unit}]')
        ax.set_xlim(problem.state[i].low, problem.state[i].high)
    axes[0][0].legend(fontsize=7, loc='upper right')
    fig.suptitle(f'{problem.name}: {len(policy)} exemplars, return {episode.ret:.1f}, '
                 f'delta* {episode.delta_star:.4f}')
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
