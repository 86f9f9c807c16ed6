"""Checks of a problem YAML beyond its parsing (``sim_nodes.problem``): every section is
checked before anything starts, so a bad value is one ``ConfigError`` line naming the file
and the field, never a crash in a node or a run that cannot work.

* sizes: state coordinates, actions, ``episode.substeps`` and ``n_step``, and the Q-learning
  tiles per coordinate are bounded (``substeps: 1e12`` would hang every step);
* ``episode.ends_in_goal``: true or false when given;
* ``ros``: ``joints`` (distinct names covering the state layout and the actuator),
  ``frame_id``, ``topics`` (known roles, valid ROS 2 topic names) and ``qos`` (known
  choices, a bounded depth);
* physics: the parameters the model lists in ``POSITIVE`` are > 0, those in ``ORDERED``
  increase (a track's ends), and a trial of two MDP
  steps with every action from the initial state gives finite states and rewards (zero
  masses give nan, which would otherwise read as a goal reached).
"""
from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from sim_nodes.errors import ConfigError

MAX_DIM = 64                   # state coordinates
MAX_ACTIONS = 256
MAX_SUBSTEPS = 10_000          # integration substeps per MDP step
MAX_N_STEP = 1_000_000         # MDP steps per episode
MAX_TILES = 10_000             # Q-learning tiles per coordinate
MAX_QOS_DEPTH = 100_000
TRIAL_STEPS = 2
TOPIC_ROLES = ('state', 'command', 'reward', 'event', 'exemplar', 'command_stamped',
               'markers')
# each role's topic unless ``ros.topics`` names another (relative names: in the node's
# namespace)
DEFAULT_TOPICS = {'state': 'joint_states', 'command': 'command', 'reward': 'reward',
                  'event': 'episode_event', 'exemplar': 'exemplar_index',
                  'command_stamped': 'command_stamped', 'markers': 'markers'}
# topics the nodes publish besides the roles' (the MuJoCo robot's effort command, the
# simulated clock, diagnostics, and rclpy's own): no role may take one of these names
EFFORT_TOPIC = 'effort_controller/commands'
RESERVED_TOPICS = (EFFORT_TOPIC, 'clock', 'diagnostics', 'rosout', 'parameter_events')
QOS_CHOICES = {'reliability': ('reliable', 'best_effort'),
               'durability': ('volatile', 'transient_local'),
               'history': ('keep_last', 'keep_all')}
_TOPIC_RE = re.compile(r'(~/|/)?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*')
_JOINT_RE = re.compile(r'[A-Za-z_][A-Za-z0-9_./-]{0,99}')
_FRAME_RE = re.compile(r'[A-Za-z_][A-Za-z0-9_./-]{0,99}')


def _unknown(doc: dict, known, where: str) -> None:
    extra = [str(k)[:40] for k in doc if k not in known]
    if extra:
        raise ConfigError(f'{where}: unknown key {extra[0]!r} (known: {", ".join(known)})')


def check_sizes(source: str, dim: int, actions: int, substeps: int, n_step: int,
                tiles: int) -> None:
    """ConfigError if a size of the problem is beyond what a run can afford."""
    for what, value, top in (('state', dim, MAX_DIM), ('actions', actions, MAX_ACTIONS),
                             ('episode.substeps', substeps, MAX_SUBSTEPS),
                             ('episode.n_step', n_step, MAX_N_STEP),
                             ('q_learning.tiles_per_dim', tiles, MAX_TILES)):
        if value > top:
            raise ConfigError(f'{source}: {what}: at most {top}, got {value}')


def check_episode(episode: dict, source: str) -> None:
    """The optional switches of ``episode``."""
    value = episode.get('ends_in_goal', True)
    if not isinstance(value, bool):
        raise ConfigError(f'{source}: episode.ends_in_goal: expected true or false, '
                          f'got {str(value)[:40]!r}')


def check_ros(ros: dict, source: str, joints_needed: list[str]) -> None:
    """The ``ros:`` section: every key a node reads, checked (see the module doc)."""
    _unknown(ros, ('joints', 'frame_id', 'topics', 'qos'), f'{source}: ros')
    if 'joints' in ros:
        joints = ros['joints']
        if not isinstance(joints, list) or not 1 <= len(joints) <= MAX_DIM or \
                not all(isinstance(j, str) and _JOINT_RE.fullmatch(j) for j in joints):
            raise ConfigError(f'{source}: ros.joints: expected a list of 1 to {MAX_DIM} '
                              f'joint names, got {str(joints)[:60]}')
        if len(set(joints)) != len(joints):
            raise ConfigError(f'{source}: ros.joints: duplicate joint names {joints}')
        missing = [j for j in joints_needed if j not in joints]
        if missing:
            raise ConfigError(f'{source}: ros.joints: {missing[0]!r} (of the state layout '
                              f'or actuator.joint) is not listed')
    frame = ros.get('frame_id', 'x')
    if not isinstance(frame, str) or not _FRAME_RE.fullmatch(frame):
        raise ConfigError(f'{source}: ros.frame_id: expected a frame name, '
                          f'got {str(frame)[:40]!r}')
    topics = ros.get('topics') or {}
    if not isinstance(topics, dict):
        raise ConfigError(f'{source}: ros.topics: expected a mapping')
    _unknown(topics, TOPIC_ROLES, f'{source}: ros.topics')
    for role, name in topics.items():
        if not isinstance(name, str) or len(name) > 200 or not _TOPIC_RE.fullmatch(name):
            raise ConfigError(f'{source}: ros.topics.{role}: expected a ROS topic name, '
                              f'got {str(name)[:40]!r}')
    _check_distinct_topics({**DEFAULT_TOPICS, **topics}, source)
    qos = ros.get('qos') or {}
    if not isinstance(qos, dict):
        raise ConfigError(f'{source}: ros.qos: expected a mapping')
    _unknown(qos, (*QOS_CHOICES, 'depth'), f'{source}: ros.qos')
    for key, choices in QOS_CHOICES.items():
        if key in qos and qos[key] not in choices:
            raise ConfigError(f'{source}: ros.qos.{key}: expected one of '
                              f'{", ".join(choices)}, got {str(qos[key])[:40]!r}')
    depth = qos.get('depth', 10)
    if isinstance(depth, bool) or not isinstance(depth, int) or \
            not 1 <= depth <= MAX_QOS_DEPTH:
        raise ConfigError(f'{source}: ros.qos.depth: expected an integer in '
                          f'[1, {MAX_QOS_DEPTH}], got {str(depth)[:40]!r}')


def _check_distinct_topics(names: dict, source: str) -> None:
    """Every role on a topic of its own (each carries its own message type), none on a topic
    the nodes publish otherwise; a leading '/' does not make a name another."""
    taken = {name: f'the nodes\' own {name!r}' for name in RESERVED_TOPICS}
    for role, name in names.items():
        plain = name.lstrip('/')
        if plain in taken:
            raise ConfigError(f'{source}: ros.topics.{role}: {name!r} is the topic of '
                              f'{taken[plain]}; each role needs a topic of its own')
        taken[plain] = f'ros.topics.{role}'


def check_physics(problem: Any) -> None:
    """Positive parameters, then a finite trial (see the module doc)."""
    from sim_nodes.models import model_module
    module = model_module(problem.model)
    for name in getattr(module, 'POSITIVE', ()):
        value = problem.physics.get(name)
        if value is not None and not value > 0:
            raise ConfigError(f'{problem.source}: physics.{name}: must be > 0, got {value}')
    ordered = [(name, problem.physics.get(name)) for name in getattr(module, 'ORDERED', ())]
    for (low, a), (high, b) in zip(ordered, ordered[1:]):
        if a is not None and b is not None and not a < b:
            raise ConfigError(f'{problem.source}: physics.{low} ({a}) must be below '
                              f'physics.{high} ({b})')
    params = problem.params()
    for action in problem.actions:
        s = problem.initial_state.copy()
        for _ in range(TRIAL_STEPS):
            reward = module.mdp_step(s, action, params)
            if not (math.isfinite(reward) and np.all(np.isfinite(s))):
                raise ConfigError(f'{problem.source}: physics: the model gives a non-finite '
                                  f'state or reward (action {action} from the initial state); '
                                  'check the parameters')
