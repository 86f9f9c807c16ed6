"""Decision-time planning on top of a policy: the plan of its own episode, re-planned.

A trained exemplar policy is a memorised trajectory: off its one initial state, or on a plant
that is not its model, it rarely gets where its episode got.  What it does give is a good
guess.  ``Replanner`` keeps a plan, one action for every step of the episode, the policy's
own undisturbed episode at first (the action nearest zero after its end).  Every ``every``
MDP steps it improves the rest of the plan on its model, from the state predicted
for when the command it issues now will act (``delay`` steps of the model with the
commands in flight, as the delay-aware selector predicts): ``rounds`` rounds of a (1, 16)
evolution strategy, 16 mutants of the plan (each with one to three of the next ``window``
actions drawn anew) stepped side by side by the engine's model kernel, the best of them kept
when it is no worse than the plan.  A plan's score: the steps until it enters S_delta, else
1e4 (1 + its delta*): the soonest entry, else the nearest approach.  Then it issues the
plan's action for this step.  Re-planning from what it sees every few steps is the
feedback.  With ``replan_fit`` the model it plans and predicts on is not the nominal one but
the masses and lengths fitted to the transitions seen so far in the episode
(``sapga_ros.evaluation.model_fit``).  With ``replan_filter`` (the sensors' noise sigma) it
plans, predicts and hands over from a Kalman filter's estimate of the state instead of the
state seen (``sapga_ros.evaluation.state_filter``); the fit still learns from the states
seen.

The mutations are counter-based draws (``sim_nodes.draws.uniform``) keyed by the planner's
seed and the step, so a planned episode is a pure function of the states seen: the same for
any thread count.

A hold task (an episode that does not end in S_delta) is not scored by entering S_delta,
which is not staying: its planner aims at the region of the classical LQR about the upright
state and hands over to that LQR where the model says it settles from the state predicted
for its command (``sapga_ros.evaluation.hold_catch``; the plan's score is the steps until it
enters ``AIM`` x that region, else 10^4 (1 + its smallest x'Px / c)).  A hold task without a
classical design is refused.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from sapga_ros.errors import SapgaError
from sim_nodes.disturbance import Disturbance, Plant, load_disturbance
from sapga_ros.evaluation.engine import predict_lanes, remember_lanes
from sapga_ros.evaluation.hold_catch import REDESIGN, HoldCatch
from sapga_ros.evaluation.model_fit import ModelFit
from sapga_ros.evaluation.state_filter import StateFilter
from sim_nodes.draws import HELD_OUT, episode_key, uniform
from sim_nodes.goal import goal_arrays, goal_delta, lanes_delta
from sim_nodes.jit import kernel
from sim_nodes.models.dispatch import step_lanes
from sapga_ros.evaluation.replan_settings import ReplanSettings, check_plannable, planner_delay

PLAN_LANES = 16        # mutants of one round, stepped side by side
S_PLAN = 7             # the planner's stream of draws (the disturbances use 0-4)
FAR = 1e4              # a plan that never enters S_delta scores FAR (1 + its delta*)
START_TOL = 0.006      # a state this near the initial one in every coordinate, as a share
RESTART_AFTER = 50     # of its range, is a start once the plan has run this many steps
MAX_PLAN = 100_000     # steps of a plan at most (each re-plan scores the rest of it)


@kernel(nogil=True)
def lanes_quad(S, lanes, best, is_angle, P, out):
    """out[k] = x'Px of lane k's state minus ``best`` (angles the short way round)."""
    dim = S.shape[0]
    x = np.empty(dim)
    for k in range(lanes):
        for i in range(dim):
            d = S[i, k] - best[i]
            x[i] = d - 2.0 * math.pi * np.rint(d / (2.0 * math.pi)) if is_angle[i] else d
        q = 0.0
        for i in range(dim):
            row = 0.0
            for j in range(dim):
                row += P[i, j] * x[j]
            q += x[i] * row
        out[k] = q


@kernel(nogil=True)
def plan_scores(model, s, cand, t0, n, p, actions, best, inv_scale, fixed, is_angle, delta,
                P, c, S, a, r, d, score, bound=-1.0):
    """score[k] of plan cand[k] (action indices) from the state s, its steps t0..n-1 on the
    model with parameters p, the 16 plans side by side.  With ``c`` > 0 the goal is the
    ellipsoid x'Px <= c about ``best`` instead of S_delta (a hold task's catch), and a plan
    that never enters it scores FAR (1 + its smallest x'Px / c).

    ``bound`` >= 0 asks only which plan scores least when that is <= ``bound``: the
    stepping stops once no plan still outside the goal can score lower, after the step
    ``bound`` or the step the first plan entered, whichever is first and below FAR (a plan
    that never enters scores at least FAR, so an entry after FAR steps bounds nothing);
    such a plan scores FAR (1 + its smallest distance so far).  If full scoring's least is
    <= ``bound``, the least score and its first lane are full scoring's and every other
    score is above it; if not, every score is above ``bound`` too.  So a round of
    ``improve_plan`` decides as it would on full scores."""
    lanes = cand.shape[0]
    first = np.zeros(lanes, dtype=np.int64)
    dmin = np.full(lanes, np.inf)
    for k in range(lanes):
        S[:, k] = s
    left = lanes
    goal = c if c > 0.0 else delta
    stop = bound if 0.0 <= bound < FAR else np.inf   # no plan outside the goal beats it
    for t in range(t0, n):
        for k in range(lanes):
            a[k] = actions[cand[k, t]]
        step_lanes(model, S, a, p, lanes, r)
        if c > 0.0:
            lanes_quad(S, lanes, best, is_angle, P, d)
        else:
            lanes_delta(S, lanes, best, inv_scale, fixed, is_angle, d)
        for k in range(lanes):
            if first[k] == 0:
                dmin[k] = d[k] if d[k] < dmin[k] else dmin[k]
                if d[k] <= goal:
                    first[k] = t - t0 + 1
                    left -= 1
                    if bound >= 0.0 and first[k] < stop and first[k] < FAR:
                        stop = first[k]     # (a plan never entering scores FAR and more)
        if left == 0 or t - t0 + 1 >= stop:
            break
    for k in range(lanes):
        score[k] = first[k] if first[k] > 0 else FAR * (
            1.0 + (dmin[k] / c if c > 0.0 else dmin[k]))


@kernel(nogil=True)
def improve_plan(model, s, plan, t0, n, p, actions, best, inv_scale, fixed, is_angle, delta,
                 P, c, rounds, window, key, prune=True):
    """Improve plan[t0:n] in place from the state s (see the module docstring; the goal as
    ``plan_scores`` takes it); its score.  ``prune``: score each round's plans only as far
    as deciding the round needs (the same plan and score as scoring them in full)."""
    lanes = PLAN_LANES
    dim = s.shape[0]
    cand = np.empty((lanes, n), dtype=np.int64)
    S = np.empty((dim, lanes))
    a, r, d, score = np.empty(lanes), np.empty(lanes), np.empty(lanes), np.empty(lanes)
    span = min(window, n - t0)
    na = actions.shape[0]
    counter = np.uint64(0)
    current = np.inf
    for rnd in range(rounds):
        for k in range(lanes):
            cand[k, :] = plan
            if rnd == 0 and k == 0:
                continue                 # the plan itself: its score
            m = 1 + int(3.0 * uniform(key, S_PLAN, counter))
            counter += np.uint64(1)
            for _ in range(m):
                j = t0 + int(span * uniform(key, S_PLAN, counter))
                cand[k, j] = int(na * uniform(key, S_PLAN, counter + np.uint64(1)))
                counter += np.uint64(2)
        # only the least score and whether it is <= the plan's matter (see plan_scores)
        plan_scores(model, s, cand, t0, n, p, actions, best, inv_scale, fixed, is_angle,
                    delta, P, c, S, a, r, d, score,
                    (current if rnd > 0 else np.inf) if prune else -1.0)
        if rnd == 0:
            current = score[0]
        k_best = 0
        for k in range(1, lanes):
            if score[k] < score[k_best]:
                k_best = k
        if score[k_best] <= current:
            current = score[k_best]
            plan[:] = cand[k_best]
    return current


def first_plan(policy, n_step: int, delta: float) -> np.ndarray:
    """The policy's own undisturbed episode (goal difficulty ``delta``) as action indices,
    then the action nearest zero to the end of ``n_step`` steps."""
    from sapga_ros.evaluation.evaluator import run_policy_episode
    problem = policy.problem
    actions = np.asarray(problem.action_values, dtype=np.float64)
    ep = run_policy_episode(policy, delta, n_step)
    plan = np.full(n_step, int(np.argmin(np.abs(actions))), dtype=np.int64)
    for t, value in enumerate(ep.actions[:n_step]):
        plan[t] = int(np.argmin(np.abs(actions - value)))
    return plan


class Replanner:
    """The planning controller of one problem (see the module docstring): ``reset()`` at an
    episode's start, ``act(seen)`` at every step."""

    def __init__(self, problem, plan: np.ndarray, settings: ReplanSettings, delta: float,
                 delay: int = 0) -> None:
        check_plannable(problem)
        if len(plan) > MAX_PLAN:
            raise SapgaError(f're-planning: a plan of {len(plan)} steps is longer than '
                             f'{MAX_PLAN} (every re-plan scores the rest of it)')
        from sapga_ros.evaluation.evaluator import model_id
        self.problem, self.settings, self.delta, self.delay = problem, settings, delta, delay
        self.first = np.ascontiguousarray(plan, dtype=np.int64)
        self.model = model_id(problem.model)
        self.p = problem.params()
        self.actions = np.asarray(problem.action_values, dtype=np.float64)
        self.goal = goal_arrays(problem)
        self.key = np.uint64(episode_key(settings.replan_seed, 0, 0, 0))  # a numpy word
        self._one = (np.empty((problem.dim, 1)), np.empty(1), np.empty(1))
        self.fit = ModelFit(problem, self.model, settings.replan_fit) \
            if settings.replan_fit > 0 else None
        # a hold task: the planner aims at the LQR's region and hands over where it settles
        self.catch = None if problem.ends_in_goal else HoldCatch(problem, delay)
        self.filter = StateFilter(problem, self.model, settings.replan_filter) \
            if settings.replan_filter > 0 else None
        self.ellipse = ((self.catch.P0, self.catch.aim) if self.catch is not None else
                        (np.zeros((problem.dim, problem.dim)), 0.0))
        self.reset()

    def reset(self) -> None:
        self.plan = self.first.copy()
        self.t = 0
        self.memory = np.zeros((1, self.delay))   # commands in flight (oldest first)
        self.last = None                          # (state seen, command applied) of t - 1
        self.applied = 0.0                        # the command applied during step t - 1
        if self.fit is not None:
            self.fit.reset()
            self.p = self.fit.params
        if self.catch is not None:
            self.catch.reset()
        if self.filter is not None:
            self.filter.reset()

    def predict(self, seen: np.ndarray) -> np.ndarray:
        """The state when a command issued now acts: the planner's model (nominal, or fitted)
        stepped with the commands in flight."""
        predicted, a, r = self._one
        predict_lanes(self.model, seen.reshape(-1, 1), self.memory, self.delay, self.p,
                      predicted, a, r)
        return predicted[:, 0].copy()

    def at_start(self, seen: np.ndarray) -> bool:
        """Whether ``seen`` is within START_TOL of its range of the problem's initial state
        in every coordinate (angles the short way round)."""
        d = np.abs(np.asarray(seen, dtype=np.float64) - self.problem.initial_state)
        angle = self.problem.is_angle
        d[angle] = np.minimum(d[angle] % (2 * np.pi), 2 * np.pi - d[angle] % (2 * np.pi))
        return bool(np.all(d <= START_TOL * self.problem.ranges))

    def act(self, seen: np.ndarray) -> float:
        """The action to issue at this step for the state seen.  A state near the initial
        one after RESTART_AFTER steps starts the plan again (a new episode: a robot or a
        simulator whose start is spread cannot say so otherwise)."""
        seen = np.asarray(seen, dtype=np.float64)
        if self.t >= RESTART_AFTER and self.at_start(seen):
            self.reset()
        if self.fit is not None and self.last is not None:
            self.fit.add(*self.last, seen)
            self.p = self.fit.params
        n = len(self.plan)
        t = min(self.t, n - 1)
        replan = self.t % self.settings.replan_every == 0 and self.t < n
        # what the plan and the catch start from: the state seen, or the filter's estimate
        # (the model fit learns from the states seen)
        estimate = seen if self.filter is None else \
            self.filter.update(seen, self.applied, self.p)
        s = self.predict(estimate) if replan or self.catch is not None else None
        if replan:
            # scored to the plan's end: with a delay its last commands act after the
            # episode's, so an entry planned in its last ``delay`` steps does not happen
            key = np.uint64(episode_key(self.key, self.t, 0, 0))
            improve_plan(self.model, s, self.plan, t, n, self.p, self.actions, *self.goal,
                         self.problem.is_angle, self.delta, *self.ellipse,
                         self.settings.replan_rounds, self.settings.replan_window, key)
        value = float(self.actions[self.plan[t]])
        if self.catch is not None:
            if self.fit is not None and self.t % REDESIGN == 0:
                self.catch.design(self.p)
            caught = self.catch.command(s, self.p)
            value = value if caught is None else caught
        # the command the plant applies during this step: the oldest in flight, or without a
        # delay the one issued now
        self.applied = float(self.memory[0, 0]) if self.delay else value
        if self.fit is not None:
            self.last = (seen.copy(), self.applied)
        if self.delay:
            remember_lanes(self.memory, self.delay, np.full(1, value))
        self.t += 1
        return value


class PlanningSelector:
    """What the policy node runs with ``replan``: a ``StateSelector``'s interface over a
    ``Replanner`` whose first plan is ``policy``'s own episode at the policy's delta.  Its
    actions come from no exemplar (index -1)."""

    stateful = True          # its plan and commands in flight: reset when an episode starts

    def __init__(self, policy, settings: ReplanSettings, delay: int = 0) -> None:
        from sapga_ros.policies.kinds import policy_delta
        problem = policy.problem
        delta = policy_delta(policy)
        self.policy = policy
        self.planner = Replanner(problem, first_plan(policy, problem.n_step, delta), settings,
                                 delta, planner_delay(policy, delay))

    def __len__(self) -> int:
        return len(self.policy)

    def reset(self) -> None:
        self.planner.reset()

    def select(self, state: np.ndarray) -> tuple[int, float]:
        return -1, self.planner.act(np.asarray(state, dtype=np.float64))


def planned_episode(planner: Replanner, plant: Plant, key: tuple) -> dict:
    """One episode of ``planner`` on ``plant`` (draw key ``key``): what the engine records
    of an episode (return, steps, delta*, first entry, contacts)."""
    problem = planner.problem
    best, inv_scale, fixed = planner.goal
    s = plant.reset(key)
    planner.reset()
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    dstar = goal_delta(s, best, inv_scale, fixed, problem.is_angle)
    ret, first, held, contacts, steps = 0.0, 0, 0, 0, 0
    fail = not math.isnan(problem.fail_charge)
    for t in range(plant.n_step):
        a[0] = plant.command(planner.act(plant.observe(s)))
        plant.push(s)
        S[:, 0] = s
        step_lanes(planner.model, S, a, plant.params, 1, r)
        s = S[:, 0].copy()
        plant.advance()
        steps = t + 1
        ret += r[0]
        d = goal_delta(s, best, inv_scale, fixed, problem.is_angle)
        dstar = min(dstar, d)
        hit = r[0] < problem.contact_below
        contacts += hit
        if d <= planner.delta:
            first = first or steps
            held += 1
            if problem.ends_in_goal:
                break
            ret += problem.hold_bonus
        if hit and fail:
            ret += (plant.n_step - steps) * problem.fail_charge
            break
    return {'return': ret, 'steps': steps, 'delta_star': dstar, 'first_entry': first,
            'held': held, 'contacts': contacts}


def profile_of(disturbance: str | Disturbance) -> Disturbance:
    """A profile given by name (or .yaml file), or the profile itself (a scaled one)."""
    if isinstance(disturbance, Disturbance):
        return disturbance
    return load_disturbance(disturbance)


def planned_episodes(policy, delta: float, disturbance: str | Disturbance, episodes: int,
                     seed: int, settings: ReplanSettings, delay: int = 0,
                     n_step: int | None = None, jobs: int = 1) -> list[dict]:
    """``episodes`` held-out episodes of profile ``disturbance`` (the draws ``sapga eval
    --disturbance`` runs the policy alone on) with the policy's plan re-planned; the same
    for any ``jobs``."""
    problem = policy.problem
    n = problem.resolve('n_step', n_step)
    plan = first_plan(policy, n, delta)
    profile = profile_of(disturbance)

    def run(e: int) -> dict:
        planner = Replanner(problem, plan, settings, delta, delay)
        return planned_episode(planner, Plant(problem, profile, n), (seed, 0, HELD_OUT, e))

    if jobs <= 1:
        return [run(e) for e in range(episodes)]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(run, range(episodes)))


def replanned_episode(policy, delta: float, n_step: int | None = None,
                      settings: ReplanSettings = ReplanSettings(), delay: int = 0) -> dict:
    """The undisturbed re-planned episode as ``Episode.summary()`` gives an episode."""
    return episode_summary(planned_episodes(policy, delta, 'none', 1, 0, settings,
                                            planner_delay(policy, delay), n_step)[0])


def episode_summary(o: dict) -> dict:
    """A planned episode (``planned_episodes``) as ``Episode.summary()`` gives an episode."""
    from sim_nodes.goal import hold_measures
    return {'return': o['return'], 'delta_star': o['delta_star'], 'steps': o['steps'],
            'reached': o['first_entry'] > 0,
            **hold_measures(o['first_entry'], o['held'], o['steps'], o['contacts'])}


def replanned(policy, delta: float, disturbance: str | Disturbance, episodes: int, seed: int,
              settings: ReplanSettings, delay: int = 0, n_step: int | None = None,
              jobs: int = 1) -> dict:
    """``sapga eval --replan``: the robustness summary (``evaluation.robust.summary``) of
    ``planned_episodes``, with the planner's settings."""
    from sapga_ros.evaluation.robust import summary
    from sapga_ros.policies.exemplar import ExemplarPolicy
    if not isinstance(policy, ExemplarPolicy):
        raise SapgaError('re-planning starts from the episode of an exemplar or classical '
                         'policy, not of a Q-learning table')
    out = planned_episodes(policy, delta, disturbance, episodes, seed, settings, delay, n_step,
                           jobs)
    profile = profile_of(disturbance).name
    return {**summary(policy.problem, delta, profile, seed, delay,
                      [o['first_entry'] for o in out], [o['held'] for o in out],
                      [o['steps'] for o in out], [o['contacts'] for o in out],
                      [o['delta_star'] for o in out], [o['return'] for o in out]),
            'replan': {'rounds': settings.replan_rounds, 'window': settings.replan_window,
                       'every': settings.replan_every, 'seed': settings.replan_seed,
                       'fit': settings.replan_fit, 'filter': settings.replan_filter}}
