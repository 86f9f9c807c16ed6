"""The compiled controller behind an exemplar selector: LQR catch and energy swing-up.

``choose`` is what the episode engine, the traced episode and the ROS policy node call for
every state: when the policy carries a controller (``ctl[MODE] != 0``) it is asked first,
else, or when it declines, the exemplar selector ``select`` answers.  Modes:

* ``CATCH`` (the hybrid): inside the region x'Px <= c around the upright state the LQR
  answers, outside the exemplars do;
* ``CLASSICAL``: inside the region the LQR answers, outside the energy swing-up does (no
  exemplars);
* ``AHEAD``: the exemplars answer for the state predicted for when the command arrives
  (below; no LQR, no region): an exemplar policy designed for an actuation delay.

x is the state minus the best state, angles as the signed shortest way round.  Every
controller action is the problem's action nearest to the continuous command (ties to the
lowest index): the quantisation a real actuator set imposes.  The reported exemplar index
of a controller step is -1.

Actuation delay: a controller designed for a plant that applies each command d MDP steps
late (``ctl[DELAY]`` = d > 0) remembers the d commands it issued last (``mem``, oldest
first, whatever chose them; zero at an episode's start) and acts on the state predicted
for when its command arrives: the compiled MDP step of the nominal model applied d times
from the state seen with the commands in flight (a Smith predictor with the model
itself; near the top, where the model is linear, the LQR of -K on this prediction is the
LQR of the state augmented with the commands in flight).  The region test, -Kx and the
swing-up all act on the prediction, so on the undisturbed plant with latency d the
controlled episode is the undelayed one, d steps later.  d = 0 is the undelayed
controller.  In ``AHEAD`` mode the exemplar selector acts on the prediction (in a hybrid,
``CATCH``, only the LQR does, as its files were designed).

``ctl`` (float64, ``sapga_ros.policies.controller_row``) layout: [mode, c, swing-up kind,
delay, NG swing-up constants, K (D), P (D*D)].
The swing-up pumps energy towards the upright energy E_top with the sign of the power the
actuator can feed (sign(0) = +1, so a pendulum at rest gets a first push).
Swing-up constants, acrobot (Spong-style energy pumping with a PD on the elbow):
[M11 const, M11 cos-coef, M12 const, M12 cos-coef, M22, g-coef 1, g-coef 2, E_top, kp, kd,
ke]; cart (Astrom-Furuta on the summed pole energy, plus cart centring):
[m1 l1, m2 l2, J1, J2, g, E_top, ke, kx, kv, x index of the poles' first angle].
"""
import math

import numpy as np
from sim_nodes.jit import kernel

from sapga_ros.exemplars.selectors import select
from sapga_ros.policies.styles import STATE_ACTION
from sim_nodes.models.dispatch import step_lanes
from sapga_ros.policies.controller_row import (AHEAD, CATCH, CLASSICAL, DELAY, C, GAINS, HEAD,
                                               MODE, NG, NONE, SWING, SWING_ACROBOT,
                                               SWING_CART)


@kernel(inline='always')
def signed_angle(d):
    """d wrapped to (-pi, pi]."""
    d = d % (2.0 * math.pi)          # [0, 2pi)
    return d - 2.0 * math.pi if d > math.pi else d


@kernel(inline='always')
def sgn(v):
    """The sign, +1 at 0: a pendulum at rest gets a first push."""
    return -1.0 if v < 0.0 else 1.0


@kernel(inline='always')
def nearest_action(u, actions):
    best = 0
    for a in range(1, actions.shape[0]):
        if abs(actions[a] - u) < abs(actions[best] - u):
            best = a
    return actions[best]


@kernel(inline='always')
def predict(ctl, model, s, p, mem, w_state, w_act, w_rew, out):
    """Into ``out``: the state when a command issued now acts, ``ctl[DELAY]`` MDP steps of
    the nominal model from ``s`` with the commands in flight ``mem`` (s itself: none)."""
    for i in range(s.shape[0]):
        w_state[i, 0] = s[i]
    for m in range(int(ctl[DELAY])):
        w_act[0] = mem[m]
        step_lanes(model, w_state, w_act, p, 1, w_rew)
    for i in range(s.shape[0]):
        out[i] = w_state[i, 0]


@kernel
def lqr(ctl, s, best, is_angle, x):
    """(inside x'Px <= c, continuous LQR command -Kx); x (D,) is scratch."""
    dim = s.shape[0]
    for i in range(dim):
        d = s[i] - best[i]
        x[i] = signed_angle(d) if is_angle[i] else d
    quad = 0.0
    base = HEAD + dim
    for i in range(dim):
        row = 0.0
        for j in range(dim):
            row += ctl[base + i * dim + j] * x[j]
        quad += x[i] * row
    u = 0.0
    for i in range(dim):
        u -= ctl[HEAD + i] * x[i]
    return quad <= ctl[C], u


@kernel
def swing_up(ctl, s):
    """The energy-based swing-up's continuous command."""
    g = ctl[GAINS:GAINS + NG]
    if ctl[SWING] == SWING_ACROBOT:
        t1, t2, w1, w2 = s[0], s[1], s[2], s[3]
        c2 = math.cos(t2)
        m11 = g[0] + g[1] * c2
        m12 = g[2] + g[3] * c2
        m22 = g[4]
        kinetic = 0.5 * (m11 * w1 * w1 + 2.0 * m12 * w1 * w2 + m22 * w2 * w2)
        energy = kinetic + g[5] * math.sin(t1) + g[6] * math.sin(t1 + t2)
        q2 = signed_angle(t2)
        return -g[8] * q2 - g[9] * w2 + g[10] * (g[7] - energy) * sgn(w2)
    if ctl[SWING] == SWING_CART:
        i = int(g[9])
        x, v = s[0], s[1]
        t1, t2, w1, w2 = s[i], s[i + 1], s[i + 2], s[i + 3]
        energy = (0.5 * g[2] * w1 * w1 + g[0] * g[4] * math.sin(t1)
                  + 0.5 * g[3] * w2 * w2 + g[1] * g[4] * math.sin(t2))
        pump = g[0] * math.sin(t1) * w1 + g[1] * math.sin(t2) * w2  # dE/dt per unit accel.
        return g[6] * (g[5] - energy) * sgn(pump) - g[7] * x - g[8] * v
    return 0.0


@kernel(inline='always')
def remember(ctl, mem, action):
    """Note the command issued in the delayed controller's memory (oldest first)."""
    delay = int(ctl[DELAY])
    for m in range(delay - 1):
        mem[m] = mem[m + 1]
    if delay > 0:
        mem[delay - 1] = action


@kernel(inline='always')   # inlined into the episode loop, as the selector is
def choose(style, model, s, ex, ex2, act, val, n, actions, p, inv_range, is_angle, radius2,
           goal_u, progress, used, u, acc, w_state, w_act, w_rew, ctl, best, x, mem):
    """(exemplar index, action value, new progress): ``select`` behind the controller
    ``ctl`` (see the module docstring; x (2D,) is scratch, ``mem`` the commands in flight,
    at least ``ctl[DELAY]`` of them)."""
    if ctl[MODE] == NONE:
        return select(style, model, s, ex, ex2, act, val, n, actions, p, inv_range, is_angle,
                      radius2, goal_u, progress, used, u, acc, w_state, w_act, w_rew)
    dim = s.shape[0]
    ahead = x[dim:]                       # the state the command will act on
    predict(ctl, model, s, p, mem, w_state, w_act, w_rew, ahead)
    inside, command = False, 0.0
    if ctl[MODE] != AHEAD:
        inside, command = lqr(ctl, ahead, best, is_angle, x)
    if inside:
        j, action = -1, nearest_action(command, actions)
    elif ctl[MODE] == CLASSICAL:
        j, action = -1, nearest_action(swing_up(ctl, ahead), actions)
    else:   # the exemplars: on the prediction (AHEAD), on the state seen (a hybrid's)
        j, action, progress = select(style, model, ahead if ctl[MODE] == AHEAD else s, ex,
                                     ex2, act, val, n, actions, p, inv_range, is_angle,
                                     radius2, goal_u, progress, used, u, acc, w_state, w_act,
                                     w_rew)
    remember(ctl, mem, action)
    return j, action, progress


def _uniform_delay(ctl: np.ndarray, style: int, mode: int) -> int | None:
    """d if the batch is state-action and every controller row is of ``mode`` with one
    delay d, else None (None compiles the engine's code for that case out of its loop)."""
    if style != STATE_ACTION or ctl.shape[0] == 0 or ctl.shape[1] <= DELAY or \
            np.any(ctl[:, MODE] != mode):
        return None
    delays = ctl[:, DELAY]
    return int(delays[0]) if np.all(delays == delays[0]) else None


def uniform_ahead(ctl: np.ndarray, style: int) -> int | None:
    """The episode engine's argument that makes a state-action batch whose rows are all
    ``AHEAD`` of one delay d predict its lanes side by side: d, else None."""
    return _uniform_delay(ctl, style, AHEAD)


def uniform_catch(ctl: np.ndarray, style: int) -> int | None:
    """The episode engine's argument that asks the LQR of a state-action batch of hybrids
    (rows all ``CATCH``, one delay d) lane by lane and searches the other lanes' exemplars
    together: d, else None."""
    return _uniform_delay(ctl, style, CATCH)


@kernel
def memory_width(ctl):
    """The commands in flight the controllers of ``ctl`` (P, C) remember (at least 1)."""
    width = 1
    if ctl.shape[1] > DELAY:
        for k in range(ctl.shape[0]):
            width = max(width, int(ctl[k, DELAY]))
    return width


def no_control(count: int = 1) -> np.ndarray:
    """``ctl`` rows of policies without a controller."""
    return np.zeros((count, 1))
