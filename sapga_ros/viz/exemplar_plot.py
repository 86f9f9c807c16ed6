"""Pictures of a policy's exemplars with its episode (``sapga exemplars --plot``).

For each (angle, angular velocity) pair of the state: the exemplars, drawn as their style
says (state-action: coloured by action; state-value and state-action-value: coloured by
value; via-point: numbered and joined in order; state-state: each better state joined to
its worse one), sized by how often the episode reported them, with the trajectory on top.
A 2-D problem also gets the policy map of the paper's Figure 5: the action taken everywhere.
"""
from __future__ import annotations

import numpy as np

from sapga_ros.io.atomic import save_figure_file
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.viz.episode_plot import break_wraps
from sapga_ros.viz.quiet import quiet_drawing

COLOURS = ('tab:blue', 'tab:grey', 'tab:red', 'tab:green', 'tab:orange')


def _pairs(problem) -> list[tuple[int, int]]:
    """(position, velocity) coordinate pairs that belong to the same joint; for a problem
    without such pairs, consecutive coordinates."""
    coords = problem.state
    pairs = [(i, j) for i, c in enumerate(coords) if c.field == 'position'
             for j, d in enumerate(coords) if d.field == 'velocity' and d.joint == c.joint]
    return pairs or [(i, i + 1) for i in range(0, problem.dim - 1, 2)]


def policy_map(policy: ExemplarPolicy, resolution: int = 200):
    """Action chosen over a grid of a 2-D problem's state space: (xs, ys, action values).
    A via-point policy is asked as at the start of an episode at every point."""
    problem = policy.problem
    xs = np.linspace(problem.low[0], problem.high[0], resolution)
    ys = np.linspace(problem.low[1], problem.high[1], resolution)
    selector = StateSelector(policy)
    grid = np.empty((resolution, resolution))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            selector.reset()
            grid[i, j] = selector.select(np.array([x, y]))[1]
    return xs, ys, grid


def _draw_exemplars(ax, policy: ExemplarPolicy, i: int, j: int, sizes: np.ndarray) -> None:
    problem = policy.problem
    st = policy.states
    if policy.style == 'via-point':
        ax.plot(st[:, i], st[:, j], 'o--', color='tab:purple', ms=4, lw=0.6,
                label='via-points, in order')
        for k in range(len(policy)):
            ax.annotate(str(k), (st[k, i], st[k, j]), fontsize=6)
    elif policy.style == 'state-state':
        w = policy.states2
        ax.scatter(st[:, i], st[:, j], s=sizes, c='tab:green', label='better')
        ax.scatter(w[:, i], w[:, j], s=sizes, c='tab:red', label='worse')
        ax.plot(np.stack([st[:, i], w[:, i]]), np.stack([st[:, j], w[:, j]]), 'k-', lw=0.3,
                alpha=0.4)
    elif 'value' in policy.style:
        marks = ('o', 's', '^', 'v', 'D')
        actions = range(len(problem.actions)) if policy.style == 'state-action-value' else [0]
        for a in actions:
            sel = policy.actions == a
            label = f'action {problem.actions[a]:g}' if len(actions) > 1 else 'exemplar'
            pts = ax.scatter(st[sel, i], st[sel, j], s=sizes[sel], c=policy.values[sel],
                             cmap='viridis', marker=marks[a % len(marks)], label=label,
                             vmin=policy.values.min(), vmax=policy.values.max())
        ax.figure.colorbar(pts, ax=ax, label='value')
    else:
        values = policy.action_values
        for a, colour in zip(problem.actions, COLOURS):
            sel = values == a
            ax.scatter(st[sel, i], st[sel, j], s=sizes[sel], c=colour,
                       label=f'action {a:g}', alpha=0.8, edgecolors='none')


@quiet_drawing()
def plot_exemplars(policy: ExemplarPolicy, episode, counts: np.ndarray, out: str) -> None:
    """Exemplars and trajectory per coordinate pair (and the policy map of a 2-D problem)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    problem = policy.problem
    pairs = _pairs(problem)
    extra = 1 if problem.dim == 2 else 0
    fig, axes = plt.subplots(1, len(pairs) + extra, figsize=(5 * (len(pairs) + extra), 4.2),
                             squeeze=False)
    sizes = 12 + 3 * np.sqrt(np.asarray(counts, dtype=float))
    if extra:
        xs, ys, grid = policy_map(policy)
        ax = axes[0][-1]
        ax.pcolormesh(xs, ys, grid, cmap='Greys', shading='auto', alpha=0.6)
        ax.plot(episode.states[:, 0], episode.states[:, 1], 'r-', lw=1, label='trajectory')
        ax.set_title(f'action {max(problem.actions):g} in dark areas', fontsize=9)
    for ax, (i, j) in zip(axes[0], pairs):
        _draw_exemplars(ax, policy, i, j, sizes)
        xs, ys = episode.states[:, i], episode.states[:, j]
        if problem.state[i].angle:            # the line breaks where the angle wraps
            ys, xs = break_wraps(ys, xs)
        ax.plot(xs, ys, 'k-', lw=0.6, alpha=0.6, label='trajectory')
        ax.set_xlabel(f'{problem.state[i].name} [{problem.state[i].unit}]')
        ax.set_ylabel(f'{problem.state[j].name} [{problem.state[j].unit}]')
        ax.set_xlim(problem.state[i].low, problem.state[i].high)
    axes[0][0].legend(fontsize=7, loc='upper right')
    fig.suptitle(f'{problem.name}, {policy.style}: {len(policy)} exemplars, return '
                 f'{episode.ret:.1f}, delta* {episode.delta_star:.4f}, {episode.steps} steps')
    fig.tight_layout()
    save_figure_file(fig, out, dpi=110)
    plt.close(fig)
