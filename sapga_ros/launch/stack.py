"""The deployment stack of the launches: recorder, simulator and policy node under a
supervisor, driven by the launch's own node (``launch_node.py``), and the episode summaries.

Every node gets the launch's namespace, remaps and ``--ros-args`` tail
(``ros_args.RosOptions``); the waits use the names as the nodes resolve them.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sapga_ros.errors import SapgaError
from sapga_ros.launch.supervisor import LaunchError, Supervisor, find_executable, write_params_file
from sapga_ros.launch.launch_node import LaunchRos
from sapga_ros.nodes.recorder_node import NODE_NAME as RECORDER
from sapga_ros.recording.events import ROLE_PUBLISHERS
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.session import free_bag_path, utc_stamp
from sapga_ros.recording.verify import recording_gaps
from sim_nodes.models.registry import sim_executable
from sim_nodes.mujoco_plant import mapping
from sim_nodes.problem_checks import EFFORT_TOPIC
from sim_nodes.problem import Problem

CONNECT_TIMEOUT_S = 90.0   # [s] for every node to start and join the graph
SETTLE_S = 1.0             # [s] after the graph is complete, for endpoints to match
STALL_S = 30.0             # [s] lockstep: no new state this long = the episode is stuck
REPUBLISH_S = 0.2          # [s] lockstep re-publish period once the simulator is let go
RECORDED_S = 30.0          # [s] for the recorder to write every message of the episodes
REREAD_S = 1.0             # [s] between reads of the bag while waiting for it to be whole


@dataclass(frozen=True)
class StackOptions:
    """What a deployment runs."""

    problem: Problem
    out: Path                      # recordings go here
    delta: float                   # goal difficulty of the simulator
    episodes: int = 1
    mode: str = 'lockstep'
    real_time_factor: float = 1.0
    engine: str = 'kernel'         # mujoco: the MuJoCo robot, driven through the mapping
    n_step: int | None = None      # MDP steps per episode (None: the problem's)
    replan: bool = False           # the policy node re-plans (sapga_ros.evaluation.replan)


@dataclass
class DeployStack:
    """Recorder, simulator and policy node under a supervisor, driven by the launcher node."""

    sup: Supervisor
    ros: LaunchRos
    opts: StackOptions
    params_dir: Path
    bag: Path | None = None             # the recording: a rosbag2 bag directory
    topics: dict[str, str] = field(default_factory=dict)   # role -> resolved topic name

    def start(self) -> None:
        """Start the recorder and the policy node (the simulator comes once the policy node
        has its policy: ``start_sim``)."""
        o = self.opts
        o.out.mkdir(parents=True, exist_ok=True)
        self.bag = free_bag_path(o.out, f'{o.problem.name}_{utc_stamp()}')
        self.topics = {role: self.ros.node.resolve_topic_name(name)
                       for role, name in self.ros.node.topics.items()}
        recorder = {'problem': o.problem.name, 'output_dir': str(o.out),
                    'bag': self.bag.name, 'delta': float(o.delta)}
        policy: dict[str, Any] = {'problem': o.problem.name, **self._loop_executor()}
        if o.replan:
            policy['replan'] = True
        if o.engine == 'mujoco':
            self.topics['effort'] = self.ros.node.resolve_topic_name(EFFORT_TOPIC)
            recorder['topics'] = [*self.ros.node.topics.values(),
                                  f'{EFFORT_TOPIC}:std_msgs/msg/Float64MultiArray']
            policy.update(robot_mapping(o.problem))
        self.spawn('recorder', 'recorder_node', recorder)
        self.spawn('policy', 'policy_node', policy)

    def start_sim(self) -> None:
        """Start the simulator, its first episode once the recorder is ready
        (``wait_for_recorder``): lockstep, silent (``go`` makes it re-publish the waiting
        state); realtime, its first tick once a command answered its first state
        (``wait_for_policy``), so no step of a realtime run is taken in lockstep."""
        o = self.opts
        self.spawn('sim', sim_executable(o.problem.model), {
            'problem': o.problem.name, 'mode': o.mode, 'delta': float(o.delta),
            'auto_reset': True, 'max_episodes': o.episodes, 'republish_period': 0.0,
            'real_time_factor': float(o.real_time_factor), 'wait_for_recorder': RECORDER,
            'recorder_timeout': CONNECT_TIMEOUT_S, 'engine': o.engine,
            'n_step': o.problem.resolve('n_step', o.n_step), **self._loop_executor()})

    def _loop_executor(self) -> dict[str, str]:
        """A recorded lockstep loop runs its two nodes on the single-threaded executor: on
        the EventsExecutor it is about three times as fast and, on a busy machine, outpaces
        the recorder, which then loses messages (``--ros-args -p executor:=events`` still
        chooses it).  Realtime runs keep the nodes' default."""
        return {'executor': 'single'} if self.opts.mode == 'lockstep' else {}

    def spawn(self, name: str, exe: str, params: dict[str, Any]) -> None:
        """Start package executable ``exe`` as child ``name`` with ``params``."""
        path = write_params_file(self.params_dir / f'{name}.yaml', params)
        self.sup.start(name, [find_executable(exe), *self.ros.options.node_args(path)])

    def wait_connected(self, extra: dict[str, tuple[int, int]] | None = None) -> None:
        """Wait until every topic of the stack has its publishers and subscribers."""
        t = self.topics             # as the nodes resolve them: namespace and remaps
        # the launcher node itself subscribes to the state and the episode events; the
        # policy node answers on command_stamped (command is for hand use); the sim and the
        # policy node both draw on markers
        needs = {t['state']: (1, 3), t['command_stamped']: (1, 2), t['command']: (0, 2),
                 t['reward']: (1, 1), t['event']: (1, 2), t['exemplar']: (1, 1),
                 t['markers']: (ROLE_PUBLISHERS['markers'], 1), **(extra or {})}
        if 'effort' in t:           # engine mujoco: the policy node's effort array
            needs[t['effort']] = (1, 2)
        node = self.ros.node
        try:
            self.sup.wait(lambda: not node.missing_links(needs), timeout=CONNECT_TIMEOUT_S,
                          what='the nodes to connect')
        except LaunchError as exc:
            if 'timed out' in str(exc):
                raise LaunchError(f'{exc}; missing: {"; ".join(node.missing_links(needs))}'
                                  ) from exc
            raise
        self.wait_recorder_ready()
        time.sleep(SETTLE_S)
        self.sup.check()
        self.sup.say('all nodes connected')

    def wait_recorder_ready(self) -> None:
        """Wait until the recorder hears every publisher of every recorded topic."""
        said = ['no answer']

        def ready() -> bool:
            answer = self.ros.trigger(self.sup, f'{RECORDER}/ready', idempotent=True)
            said[0] = answer.message
            return answer.success

        try:
            self.sup.wait(ready, timeout=CONNECT_TIMEOUT_S, what='the recorder')
        except LaunchError as exc:
            if 'timed out' in str(exc):
                raise LaunchError(f'the recorder is not ready after {CONNECT_TIMEOUT_S:g} s: '
                                  f'{said[0]}') from exc
            raise
        self.sup.say(f'recorder ready: {said[0]}')

    def go(self) -> None:
        """Let the simulator go (once the policy node has its policy): lockstep re-publishes
        the waiting state for the policy to answer; realtime is going already (it steps
        once the policy answers its first state)."""
        self.ros.node.last_new_state = time.monotonic()
        if self.opts.mode == 'lockstep':
            self.ros.set_parameters(self.sup, sim_executable(self.opts.problem.model),
                                    {'republish_period': REPUBLISH_S})

    def run_episodes(self) -> list[dict]:
        """Wait for the N episode end events (lockstep: fail if the episode stalls)."""
        node = self.ros.node
        n = self.opts.episodes

        def finished() -> list[dict] | None:
            ends = node.end_events()
            if len(ends) >= n:
                return ends[:n]
            if self.opts.mode == 'lockstep' and \
                    time.monotonic() - node.last_new_state > STALL_S:
                raise LaunchError(f'lockstep stalled: no new state for {STALL_S:g} s after '
                                  f'{node.states} states (is the policy node answering?)')
            return None

        return self.sup.wait(finished, what=f'{n} episodes')

    def recording_gaps(self, ends: list[dict]) -> list[str]:
        """What the bag lacks of the episodes that ended with ``ends`` ([]: whole)."""
        try:
            rec = read_recording(self.bag)
        except SapgaError as exc:
            return [str(exc)]
        return recording_gaps(rec, self.topics, ends, lockstep=self.opts.mode == 'lockstep')

    def wait_recorded(self, ends: list[dict]) -> None:
        """Wait until the bag on disk holds every message of the episodes, so that stopping
        the recorder loses none (a busy recorder can lag behind a lockstep episode; it
        closes a chunk every second).  After ``RECORDED_S`` the launch goes on; the bag is
        checked again once finished (``check_recording``).  The bag is read again at most
        every ``REREAD_S``: reading it takes the CPU a busy recorder needs to catch up."""
        try:
            self.sup.wait(lambda: not self.recording_gaps(ends), timeout=RECORDED_S,
                          what='the recording', every=REREAD_S)
        except LaunchError as exc:
            if 'timed out' not in str(exc):
                raise

    def check_recording(self, ends: list[dict]) -> str | None:
        """After the nodes stopped: why the finished bag is not whole, or None."""
        gaps = self.recording_gaps(ends)
        if not gaps:
            rec = read_recording(self.bag)
            if not rec.complete:
                gaps = [rec.error or 'not finished']
        return f'the recording {self.bag} is incomplete: {"; ".join(gaps)}' if gaps else None

    def recordings(self) -> list[Path]:
        """The bag written by this run's recorder (none if it wrote nothing)."""
        return [self.bag] if self.bag is not None and self.bag.is_dir() else []


def robot_mapping(problem: Problem) -> dict[str, Any]:
    """The policy node's parameters driving the MuJoCo robot of ``problem`` (its joint
    names and conventions, ``sim_nodes/mujoco_plant.py``) with an effort array."""
    joints = mapping(problem)
    rows = [joints[j] for j in problem.joints]
    return {'robot_joints': [r.robot_joint for r in rows],
            'joint_offsets': [r.offset for r in rows],
            'joint_directions': [r.direction for r in rows],
            'command_output': 'effort_array', 'effort_topic': EFFORT_TOPIC}


def offline_episode(policy: Any, delta: float, n_step: int | None = None) -> dict:
    """The policy's offline evaluation (``sapga eval --json [--max-steps N]``): return,
    delta*, steps."""
    from sapga_ros.evaluation.evaluator import run_policy_episode
    return run_policy_episode(policy, delta, n_step).summary()


def event_summary(event: dict) -> dict:
    """Return, delta*, steps of an episode end event (delta* inf as in ``sapga eval``)."""
    dstar = event.get('delta_star')
    return {'return': event.get('return'), 'delta_star': math.inf if dstar is None else dstar,
            'steps': event.get('step'),
            'reached': event.get('event') == 'goal' or event.get('first_entry_step') is not None,
            **{k: event.get(k) for k in HOLD_KEYS}}


HOLD_KEYS = ('first_entry_step', 'hold_fraction', 'rail_contacts')


def same_episode(ros_ep: dict, offline: dict) -> bool:
    """Exactly equal return, delta*, steps, goal and hold measures."""
    return all(ros_ep[k] == offline[k] for k in ('return', 'delta_star', 'steps', 'reached',
                                                 *HOLD_KEYS))


def episode_lines(ends: list[dict]) -> list[str]:
    lines = [f'{"episode":>7} {"end":<10} {"steps":>5} {"return":>12} {"delta*":>9} '
             f'{"1st in":>6} {"hold":>6} {"rail":>4}']
    for e in ends:
        s = event_summary(e)
        hold = s['hold_fraction']
        lines.append(f'{e.get("episode", "?"):>7} {e.get("event"):<10} {s["steps"]:>5} '
                     f'{s["return"]:>12.4f} {s["delta_star"]:>9.5f} '
                     f'{s["first_entry_step"] or "-"!s:>6} '
                     f'{"-" if hold is None else format(hold, ".4f"):>6} '
                     f'{s["rail_contacts"]!s:>4}')
    return lines
