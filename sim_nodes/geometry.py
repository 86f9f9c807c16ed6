"""What a state looks like: the pendulums as points and line segments.

Pure Python (no ROS, no plotting): the simulator's and the policy node's markers
(``sim_nodes/ros/markers.py``) and the stroboscopic plot of ``sapga inspect --plot``
(``sapga_ros/viz/episode_plot.py``) draw from here.  Coordinates are metres in a vertical
plane: x to the right (along the rail), z up, the pivot (or the rail's middle) at the origin.

=============  ==========================================================================
model          picture (angles counter-clockwise from +x, as the model docstrings say)
=============  ==========================================================================
acrobot        link 1 from the shoulder (0, 0), length ``l1``, at theta1; link 2 from the
               elbow, length ``2 lc2`` (uniform link: the centre of mass halfway), at
               theta1 + theta2.  Upright (pi/2, 0) puts the tip at (0, l1 + 2 lc2)
pdip           the cart at (x, 0) on a rail |x| <= x_max; pole i from the cart, length
               ``l_i`` (the model's length parameter), at theta_i
pendulum       one rod from the pivot, length ``l``, at theta
mountain_car   the car on the hill z = sin(3 x) / 3 (the slope the model's gravity term
               cos(3 x) belongs to), x in [x_min, x_max]
=============  ==========================================================================

A model missing from ``DRAWINGS`` has no picture: nothing is drawn, which is no error.
``goal_band`` gives, per state coordinate, how far S_delta reaches around the best state, and
``goal_states`` the best state and the edges of that band (positions only, velocities at
their best): drawn, they show where the goal is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

Point = tuple[float, float]             # (x, z) [m]
Segment = tuple[Point, Point]
HILL_POINTS = 60                        # samples of the mountain car's hill


@dataclass(frozen=True)
class Picture:
    """One state drawn: rods/links as segments (pivot end first), their pivots, joints and
    tips as points, and the cart's (or car's) centre."""

    links: tuple[Segment, ...] = ()
    joints: tuple[Point, ...] = ()
    body: Point | None = None

    @property
    def points(self) -> tuple[Point, ...]:
        """Every point that locates the picture: joints, then the body."""
        return self.joints + ((self.body,) if self.body is not None else ())

    @property
    def tip(self) -> Point | None:
        """The far end of the last link (None without links)."""
        return self.links[-1][1] if self.links else None


@dataclass(frozen=True)
class Drawing:
    """How a model is drawn: its pictures, the static track and the body's size."""

    picture: Callable[[Sequence[float], Mapping[str, float]], Picture]
    track: Callable[[Mapping[str, float]], tuple[Point, ...]] | None = None
    body_size: tuple[float, float] = (0.0, 0.0)    # [m] width, height; 0: no body
    body_shape: str = 'cube'                        # 'cube' | 'sphere'


def _ray(origin: Point, length: float, angle: float) -> Point:
    return (origin[0] + length * math.cos(angle), origin[1] + length * math.sin(angle))


def _acrobot(s: Sequence[float], ph: Mapping[str, float]) -> Picture:
    elbow = _ray((0.0, 0.0), ph['l1'], s[0])
    tip = _ray(elbow, 2.0 * ph['lc2'], s[0] + s[1])
    return Picture(links=(((0.0, 0.0), elbow), (elbow, tip)), joints=((0.0, 0.0), elbow, tip))


def _pdip(s: Sequence[float], ph: Mapping[str, float]) -> Picture:
    cart = (float(s[0]), 0.0)
    tips = (_ray(cart, ph['l1'], s[2]), _ray(cart, ph['l2'], s[3]))
    return Picture(links=tuple((cart, tip) for tip in tips), joints=(cart, *tips), body=cart)


def _rail(ph: Mapping[str, float]) -> tuple[Point, ...]:
    return ((-ph['x_max'], 0.0), (ph['x_max'], 0.0))


def _pendulum(s: Sequence[float], ph: Mapping[str, float]) -> Picture:
    tip = _ray((0.0, 0.0), ph['l'], s[0])
    return Picture(links=(((0.0, 0.0), tip),), joints=((0.0, 0.0), tip))


def hill_height(x: float) -> float:
    """z [m] of the mountain car's hill at x."""
    return math.sin(3.0 * x) / 3.0


def _mountain_car(s: Sequence[float], ph: Mapping[str, float]) -> Picture:
    return Picture(body=(float(s[0]), hill_height(s[0])))


def _hill(ph: Mapping[str, float]) -> tuple[Point, ...]:
    xs = np.linspace(ph['x_min'], ph['x_max'], HILL_POINTS)
    return tuple((float(x), hill_height(x)) for x in xs)


DRAWINGS: dict[str, Drawing] = {
    'acrobot': Drawing(_acrobot),
    'pdip': Drawing(_pdip, _rail, (0.4, 0.2)),
    'pendulum': Drawing(_pendulum),
    'mountain_car': Drawing(_mountain_car, _hill, (0.1, 0.1), 'sphere'),
}


def drawing(problem: Any) -> Drawing | None:
    """The drawing of the problem's model, or None when it has none."""
    return DRAWINGS.get(problem.model)


def picture(problem: Any, s: Sequence[float]) -> Picture | None:
    """State ``s`` of ``problem`` drawn, or None when its model has no drawing."""
    d = drawing(problem)
    return None if d is None else d.picture(s, problem.physics)


def track(problem: Any) -> tuple[Point, ...]:
    """The static rail or hill the model moves on (a polyline), () if none."""
    d = drawing(problem)
    return () if d is None or d.track is None else d.track(problem.physics)


def goal_band(problem: Any, delta: float) -> np.ndarray:
    """Per coordinate, the half-width of S_delta around the best state: min(scale * delta,
    fixed bound); inf where unbounded (angles: at most pi, the whole circle)."""
    scale = np.array(problem.goal_scale, dtype=np.float64)
    fixed = np.array(problem.goal_fixed, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        half = np.where(np.isnan(scale), np.inf, scale * delta)
    half = np.fmin(half, np.where(np.isnan(fixed), np.inf, fixed))
    return np.where(problem.is_angle, np.minimum(half, math.pi), half)


def goal_states(problem: Any, delta: float) -> list[np.ndarray]:
    """The best state, then per position coordinate with a band of its own (neither 0 nor
    unbounded) the two states at its edges, the other coordinates at their best."""
    best = problem.best_state
    half = goal_band(problem, delta)
    out = [best]
    for i, coord in enumerate(problem.state):
        if coord.field != 'position' or not 0 < half[i] < math.inf:
            continue
        if coord.angle and half[i] >= math.pi:
            continue                    # the whole circle: no edge to draw
        for sign in (-1.0, 1.0):
            edge = best.copy()
            edge[i] += sign * half[i]
            out.append(edge)
    return out
