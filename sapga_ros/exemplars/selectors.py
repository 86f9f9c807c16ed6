"""The action selectors of the five exemplar styles, as one compiled function.

``select(style, ...)`` maps a state to an action for a policy packed as the evaluator packs
it; the batch evaluator, the traced episode and the ROS policy node all call it, so a
lockstep ROS episode equals an offline evaluation bit for bit.  Decided where the paper is
silent:

* **state-action**: the nearest exemplar's action.  Referred: that exemplar.
* **via-point**: the via-points are visited in order.  Before selecting, every via-point
  the state lies within ``radius`` of (normalised distance) is passed, in order, starting
  at the current one; the target is the first via-point not yet passed (after the last:
  the problem's best state).  The action whose predicted next state (one MDP step of the
  same compiled model) is nearest to the target is taken.  Referred: the targeted
  via-points.  The reported index is the target's (-1 for the best state).
* **state-value**: V(s) is the value of the exemplar nearest to s (1-NN); the action
  whose predicted next state has the highest V is taken.  Referred: the exemplar of every
  candidate's estimate (each took part in the decision).  Index: the chosen candidate's.
* **state-state**: a candidate next state c scores d(c, nearest worse state) -
  d(c, nearest better state): positive when c is nearer to some "better" state than to
  every "worse" one.  The highest score is taken.  Referred: both exemplars of every
  candidate's score.  Index: the better state's pair nearest to the chosen candidate.
* **state-action-value**: Q(s, a) is the value of the exemplar nearest to s among those
  with action a (actions with no exemplar are not candidates); greedy choice.  Referred:
  every action's nearest exemplar.  Index: the chosen action's.

Ties go to the lowest index, for exemplars and for actions.
"""
import math

import numpy as np
from sim_nodes.jit import kernel
from sim_nodes.models.dispatch import step_lanes

from sapga_ros.exemplars.distance import nearest, normalize_into, sq_distance, sq_distances
from sapga_ros.policies.styles import STATE_ACTION, STATE_ACTION_VALUE, STATE_VALUE, VIA_POINT


@kernel
def predict_into(model, s, action, p, inv_range, is_angle, w_state, w_act, w_rew, out):
    """out = the normalised state one MDP step of ``action`` after the raw state s."""
    w_state[:, 0] = s
    w_act[0] = action
    step_lanes(model, w_state, w_act, p, 1, w_rew)
    normalize_into(w_state[:, 0], inv_range, is_angle, out)


@kernel(inline='always')
def select(style, model, s, ex, ex2, act, val, n, actions, p, inv_range, is_angle, radius2,
           goal_u, progress, used, u, acc, w_state, w_act, w_rew):
    """(exemplar index, action value, new progress) for the raw state s.

    ex, ex2 (D, L) normalised states (ex2: state-state's worse states), act (L,) action
    values, val (L,) values, n exemplars in use; actions: the problem's action values;
    p: the model's parameters; radius2: the via-point radius squared; goal_u: the best
    state normalised; progress: via-points passed so far in this episode (0 at its start).
    ``used[j]`` is set for each exemplar referred to.  u (D,), acc (L,), w_state (D, 1),
    w_act (1,), w_rew (1,) are scratch.
    """
    if style == STATE_ACTION:
        normalize_into(s, inv_range, is_angle, u)
        j = nearest(u, ex, n, is_angle, acc)
        used[j] = True
        return j, act[j], progress
    if style == STATE_ACTION_VALUE:
        normalize_into(s, inv_range, is_angle, u)
        sq_distances(u, ex, n, is_angle, acc)
        best_j = -1
        best_q = -math.inf
        for a in range(actions.shape[0]):
            ja = -1
            for j in range(n):
                if act[j] == actions[a] and (ja < 0 or acc[j] < acc[ja]):
                    ja = j
            if ja >= 0:
                used[ja] = True
                if best_j < 0 or val[ja] > best_q:
                    best_j = ja
                    best_q = val[ja]
        return best_j, act[best_j], progress
    target = goal_u
    if style == VIA_POINT:
        normalize_into(s, inv_range, is_angle, u)
        while progress < n and sq_distance(u, ex[:, progress], is_angle) <= radius2:
            progress += 1                     # reached: the next via-point is the target
        if progress < n:
            target = ex[:, progress]
            used[progress] = True
    best_a = 0
    best_score = -math.inf
    best_j = -1
    for a in range(actions.shape[0]):
        predict_into(model, s, actions[a], p, inv_range, is_angle, w_state, w_act, w_rew, u)
        if style == VIA_POINT:
            score = -sq_distance(u, target, is_angle)
            j = progress if progress < n else -1
        elif style == STATE_VALUE:
            j = nearest(u, ex, n, is_angle, acc)
            used[j] = True
            score = val[j]
        else:                                 # STATE_STATE (styles.STATE_STATE)
            j = nearest(u, ex, n, is_angle, acc)
            near_better = acc[j]
            k = nearest(u, ex2, n, is_angle, acc)
            used[j] = True
            used[k] = True
            score = math.sqrt(acc[k]) - math.sqrt(near_better)
        if a == 0 or score > best_score:      # strict: ties keep the lowest action
            best_a = a
            best_score = score
            best_j = j
    return best_j, actions[best_a], progress


def scratch(dim: int, length: int) -> tuple[np.ndarray, ...]:
    """The scratch arrays ``select`` takes (u, acc, w_state, w_act, w_rew)."""
    return (np.empty(dim), np.empty(max(length, 1)), np.empty((dim, 1)), np.zeros(1),
            np.zeros(1))
