"""The offline episodes a lockstep swingup must equal, with the settings the nodes ran with.

The launch gives its nodes their parameters; ``--ros-args -p name:=value`` may change some
of them.  Those the offline evaluation also takes are honoured: the simulator's
``disturbance`` and ``disturbance_seed`` (episode k of the launch is the evaluation's
held-out episode k - 1 of that seed), the policy node's ``delay``, ``replan`` and the
planner's settings.  Parameters that change nothing an episode computes (``NEUTRAL``) are
ignored.  Any other parameter, or a parameters file in ``--ros-args``, leaves the launch
without a reference: it says why instead of calling equal episodes different.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import yaml

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.replan_settings import ReplanSettings, planner_delay
from sapga_ros.launch.stack import event_summary, same_episode
from sim_nodes.params import declared

# parameters that do not change what an episode computes
NEUTRAL = frozenset({
    'executor', 'markers', 'publish_clock', 'qos_profile', 'republish_period', 'use_sim_time',
    'wait_for_policy', 'policy_timeout', 'wait_for_recorder', 'recorder_timeout',
    'load_timeout', 'chunk_size', 'compression', 'flush_period', 'queue_depth', 'split'})
PLANNER = frozenset(p.name for p in declared(ReplanSettings))
TAKEN = frozenset({'disturbance', 'disturbance_seed', 'delay', 'replan'}) | PLANNER


@dataclass(frozen=True)
class Reference:
    """One offline episode summary per launched episode (``by``: how it was computed), or
    none (``why``)."""

    episodes: list[dict] | None
    by: str = ''
    why: str = ''


def parameter_overrides(extra: tuple[str, ...]) -> dict[str, Any] | None:
    """The ``-p``/``--param name:=value`` settings of a ``--ros-args`` tail, values read as
    ROS reads them (YAML); None when the tail names a parameters file."""
    out: dict[str, Any] = {}
    for i, token in enumerate(extra):
        if token == '--params-file':
            return None
        if token in ('-p', '--param') and i + 1 < len(extra):
            name, sep, text = extra[i + 1].partition(':=')
            if sep:
                try:
                    out[name] = yaml.safe_load(text)
                except yaml.YAMLError:
                    out[name] = text
    return out


def lockstep_reference(policy, delta: float, n_step: int | None, episodes: int,
                       replan: bool, extra: tuple[str, ...]) -> Reference:
    """The offline episodes ``episodes`` lockstep episodes of ``policy`` must equal."""
    overrides = parameter_overrides(extra)
    if overrides is None:
        return Reference(None, why='--ros-args name a parameters file, whose settings the '
                                   'offline evaluation does not know')
    unknown = sorted(set(overrides) - NEUTRAL - TAKEN)
    if unknown:
        return Reference(None, why=f'--ros-args set {", ".join(unknown)}, which the offline '
                                   'evaluation does not take')
    try:
        return _reference(policy, delta, n_step, episodes, replan, overrides)
    except (SapgaError, TypeError, ValueError) as exc:   # values the nodes took, not we
        return Reference(None, why=f'the --ros-args settings do not evaluate offline: {exc}')


def _reference(policy, delta: float, n_step: int | None, episodes: int, replan: bool,
               overrides: dict[str, Any]) -> Reference:
    profile = str(overrides.get('disturbance', 'none'))
    seed = int(overrides.get('disturbance_seed', 0))
    delay = int(overrides.get('delay', 0))
    disturbed = profile != 'none'
    replan = replan or overrides.get('replan') is True
    by = 'sapga eval' + (' --replan' if replan else '') + (
        f' --disturbance {profile} --seed {seed}' if disturbed else '') + (
        f' --delay {delay}' if delay else '') + ''.join(
        f' --{name.replace("_", "-")} {overrides[name]}' for name in sorted(PLANNER)
        if replan and name in overrides)
    if replan:
        return Reference(_planned(policy, delta, n_step, episodes if disturbed else 1,
                                  profile, seed, delay, overrides), by)
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.policies.classical import run_ahead
    from sim_nodes.disturbance import load_disturbance
    from sim_nodes.draws import HELD_OUT
    ev = Evaluator(policy.problem, delta, n_step, disturbance=load_disturbance(profile))
    runs = run_ahead(policy, delay, 'policy_file')
    return Reference([ev.episode(runs, (seed, 0, HELD_OUT, e)).summary()
                      for e in range(episodes if disturbed else 1)], by)


def _planned(policy, delta: float, n_step: int | None, episodes: int, profile: str,
             seed: int, delay: int, overrides: dict[str, Any]) -> list[dict]:
    from sapga_ros.evaluation.replan import episode_summary, planned_episodes
    from sim_nodes.params import build
    settings = build(ReplanSettings, lambda name: overrides.get(
        name, getattr(ReplanSettings(), name)))
    return [episode_summary(o) for o in planned_episodes(
        policy, delta, profile, episodes, seed, settings, planner_delay(policy, delay),
        n_step)]


def matches(ends: list[dict], reference: list[dict]) -> list[int]:
    """The launched episodes (1-based) that differ from their reference (an undisturbed
    reference is one episode, which every launched episode must equal)."""
    return [k for k, e in enumerate(ends, 1)
            if not same_episode(event_summary(e), reference[min(k, len(reference)) - 1])]
