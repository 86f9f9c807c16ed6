"""The episode plot of ``sapga inspect --plot`` (sapga_ros/viz/episode_plot.py): angle lines break
where the angle wraps (no vertical jump), and the goal is marked (best value, S_delta band,
the best state's picture)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sapga_ros.recording.episodes import Episode
from sapga_ros.viz.episode_plot import break_wraps, episode_figure
from sim_nodes.geometry import goal_band
from sim_nodes.problem import load_problem

TICK_NS = 50_000_000


def test_break_wraps_puts_a_nan_between_samples_more_than_pi_apart():
    """A NaN goes exactly between the samples whose difference exceeds pi; nothing else moves."""
    t = np.arange(6.0)
    y = np.array([6.0, 6.2, 0.1, 0.3, 6.1, 6.0])     # wraps up at 2 and down at 4
    tb, yb = break_wraps(t, y)
    assert list(np.flatnonzero(np.isnan(yb))) == [2, 5]
    assert list(tb[[2, 5]]) == [1.5, 3.5]
    assert np.array_equal(yb[~np.isnan(yb)], y) and np.array_equal(tb[~np.isnan(yb)], t)
    smooth = np.array([0.0, 3.0, 6.0, 3.0])           # steps below pi: unchanged
    assert np.array_equal(break_wraps(t[:4], smooth)[1], smooth)


def spinning_acrobot(n: int = 80) -> Episode:
    """theta1 turning over the top several times (wrapped into [0, 2pi)), ending upright."""
    ep = Episode(1, start_ns=0, end_ns=(n - 1) * TICK_NS, end='goal')
    for k in range(n):
        theta1 = (1.5 * math.pi + 0.4 * k) % (2 * math.pi)
        ep.add_state(k * TICK_NS, np.array([theta1, (0.3 * k) % (2 * math.pi), 1.0, 0.5]))
    ep.commands = [(k * TICK_NS, 2.0) for k in range(n - 1)]
    return ep


def test_angle_lines_have_no_vertical_jumps_and_the_goal_is_marked():
    """In the angle panel every plotted step between finite neighbours is under pi, the line
    breaks (NaN) at each wrap; the goal's best value is a line and its band a span."""
    problem = load_problem('acrobot')
    ep = spinning_acrobot()
    fig = episode_figure(ep, problem, 'test', goal_delta=0.05)
    try:
        angle_ax = fig.axes[0]
        assert angle_ax.get_ylabel() == 'angle [rad]'
        curves = [ln for ln in angle_ax.get_lines() if ln.get_label().startswith('theta')]
        assert len(curves) == 2
        _, states = ep.trajectory()
        for line, i in zip(curves, (0, 1)):
            y = np.asarray(line.get_ydata(), dtype=float)
            wraps = int(np.sum(np.abs(np.diff(states[:, i])) > math.pi))
            assert wraps > 0 and int(np.isnan(y).sum()) == wraps
            steps = np.abs(np.diff(y))
            assert np.all(steps[np.isfinite(steps)] < math.pi)
        goal = [ln for ln in angle_ax.get_lines() if ln.get_label() == 'goal']
        assert goal and goal[0].get_ydata()[0] == pytest.approx(math.pi / 2)
        half = goal_band(problem, 0.05)[0]
        spans = [p.get_extents() for p in angle_ax.patches]
        assert spans, 'no goal band drawn'
        lo, hi = angle_ax.transData.inverted().transform(
            [[0, spans[0].y0], [0, spans[0].y1]])[:, 1]
        assert (lo, hi) == (pytest.approx(math.pi / 2 - half), pytest.approx(math.pi / 2 + half))
        strobe = fig.axes[-1]
        assert any(ln.get_color() == 'tab:green' for ln in strobe.get_lines())
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)
