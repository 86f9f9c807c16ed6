"""``sapga launch swingup``: simulator + policy node + rosbag2 recorder for N episodes.

    sapga launch swingup --policy FILE --out DIR [--mode lockstep|realtime] [--episodes N]
                         [--problem P] [--delta D] [--real-time-factor F]

The problem is the policy file's; delta is ``--delta``, else the policy's training delta
(``meta.delta``), else the problem's default.  The order makes the recording whole and a
lockstep episode exact:

1. the recorder and the policy node start; the policy file goes to the policy node (its
   ``policy_file`` parameter);
2. the simulator starts (lockstep, silent: it waits for the recorder before its first
   episode starts, then at the first state without re-publishing it);
3. the launcher waits until the ROS graph joins them all (every topic has its publisher
   and subscribers) and the recorder's ``ready`` service says it hears every publisher of
   every recorded topic, then a settling moment;
4. the simulator is let go: in lockstep it re-publishes the waiting state, the policy
   answers it and the episodes run step by step; in realtime mode it switches to realtime
   (``mode``, ``real_time_factor``) and holds command 0 until the policy's first answer, as
   any realtime start does.  ``max_episodes`` = N stops the simulator after N episodes;
5. after the N-th episode end event, and once the bag on disk holds every message of the
   episodes (a busy recorder lags behind a lockstep episode), the nodes are stopped
   (Ctrl-C), the recorder finishes its bag, and a summary is printed: per episode end,
   steps, return and delta*, the bag, and in lockstep the offline evaluation of the same
   file (``sapga eval``), which must be equal.  The launch fails (exit 1) when an episode
   differs or the finished bag lacks a message of the episodes (``recording/verify.py``).

``DeployStack`` and ``LaunchRos`` are shared with ``train_deploy``.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from sapga_ros.errors import SapgaError
from sapga_ros.recording.events import parse_event
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.session import free_bag_path, utc_stamp
from sapga_ros.recording.verify import recording_gaps
from sapga_ros.launch import (LaunchError, Supervisor, find_executable, launch_main,
                              write_params_file)
from sim_nodes.models.registry import sim_executable
from sim_nodes.ros.common import EVENT_QOS, qos_profile, spin_guarded, stamp_ns, topic_names
from sim_nodes.problem import Problem, load_problem

MODES = ('lockstep', 'realtime')
CONNECT_TIMEOUT_S = 90.0   # [s] for every node to start and join the graph
SETTLE_S = 1.0             # [s] after the graph is complete, for endpoints to match
CALL_TIMEOUT_S = 30.0      # [s] for a service call to a node
STALL_S = 30.0             # [s] lockstep: no new state this long = the episode is stuck
END_EVENTS = ('goal', 'step_limit')
REPUBLISH_S = 0.2          # [s] lockstep re-publish period once the simulator is let go
RECORDED_S = 30.0          # [s] for the recorder to write every message of the episodes


# the launcher's own ROS node ----------------------------------------------------------------

class LaunchNode(Node):
    """Hears episode events, states and the trainer's diagnostics; calls services."""

    def __init__(self, problem: Problem, **kwargs: Any) -> None:
        super().__init__('sapga_launch', **kwargs)
        self.topics = topic_names(problem)
        self._lock = threading.Lock()
        self.events: list[dict] = []
        self.last_stamp: int | None = None
        self.last_new_state = time.monotonic()
        self.states = 0                     # distinct states heard
        self.trainer: dict[str, str] | None = None
        self.create_subscription(String, self.topics['event'], self._on_event, EVENT_QOS)
        self.create_subscription(JointState, self.topics['state'], self._on_state,
                                 qos_profile(problem))
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)

    def _on_event(self, msg: String) -> None:
        event = parse_event(msg.data)       # bounded: hostile text is no event
        if event is not None:
            with self._lock:
                self.events.append(event)

    def _on_state(self, msg: JointState) -> None:
        stamp = stamp_ns(msg)
        if stamp != self.last_stamp:
            self.last_stamp = stamp
            self.last_new_state = time.monotonic()
            self.states += 1

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(': training'):
                values = {kv.key: kv.value for kv in status.values}
                values['message'] = status.message
                self.trainer = values

    def end_events(self) -> list[dict]:
        """The episode end events (goal / step_limit) heard so far, in order."""
        with self._lock:
            return [e for e in self.events if e.get('event') in END_EVENTS]

    def missing_links(self, needs: dict[str, tuple[int, int]]) -> list[str]:
        """What the graph lacks: ``needs`` maps topic -> (publishers, subscribers)."""
        missing = []
        for topic, (pubs, subs) in needs.items():
            have_p, have_s = self.count_publishers(topic), self.count_subscribers(topic)
            if have_p < pubs or have_s < subs:
                missing.append(f'{topic} ({have_p}/{pubs} publishers, '
                               f'{have_s}/{subs} subscribers)')
        return missing


class LaunchRos:
    """The launcher's rclpy context, node and executor thread (no signal handlers: the
    supervisor handles Ctrl-C)."""

    def __init__(self, problem: Problem) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = LaunchNode(problem, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True, name='launch-ros')
        self._thread.start()

    def _spin(self) -> None:
        try:
            spin_guarded(self.executor, self.node.get_logger())
        except Exception:  # noqa: BLE001 - shutdown while spinning
            pass

    def call(self, sup: Supervisor, srv_type: Any, name: str, request: Any,
             timeout: float = CALL_TIMEOUT_S) -> Any:
        """Call service ``name`` and wait for the response, watching the children."""
        client = self.node.create_client(srv_type, name)
        try:
            sup.wait(client.service_is_ready, timeout=timeout, what=f'service {name}')
            future = client.call_async(request)
            sup.wait(future.done, timeout=timeout, what=f'the response of {name}')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def trigger(self, sup: Supervisor, name: str) -> Trigger.Response:
        """Call a std_srvs/Trigger service."""
        return self.call(sup, Trigger, name, Trigger.Request())

    def set_parameters(self, sup: Supervisor, node: str, values: dict[str, Any]) -> None:
        """Set parameters of ``node``; ``LaunchError`` with the node's reason if refused."""
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=v).to_parameter_msg()
                              for k, v in values.items()]
        response = self.call(sup, SetParameters, f'/{node}/set_parameters', request)
        for (key, _), result in zip(values.items(), response.results):
            if not result.successful:
                raise LaunchError(f'{node} refused {key}: {result.reason}')

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self._thread.join(timeout=2.0)


# the deployment stack -----------------------------------------------------------------------

@dataclass(frozen=True)
class StackOptions:
    """What a deployment runs."""

    problem: Problem
    out: Path                      # recordings go here
    delta: float                   # goal difficulty of the simulator
    episodes: int = 1
    mode: str = 'lockstep'
    real_time_factor: float = 1.0


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
        self.spawn('recorder', 'recorder_node', {'problem': o.problem.name,
                                                 'output_dir': str(o.out),
                                                 'bag': self.bag.name,
                                                 'delta': float(o.delta)})
        self.spawn('policy', 'policy_node', {'problem': o.problem.name})

    def start_sim(self) -> None:
        """Start the simulator: lockstep, silent, its first episode once the recorder is
        ready (``wait_for_recorder``)."""
        o = self.opts
        self.spawn('sim', sim_executable(o.problem.model), {
            'problem': o.problem.name, 'mode': 'lockstep', 'delta': float(o.delta),
            'auto_reset': True, 'max_episodes': o.episodes, 'republish_period': 0.0,
            'real_time_factor': float(o.real_time_factor), 'wait_for_recorder': 'recorder',
            'recorder_timeout': CONNECT_TIMEOUT_S})

    def spawn(self, name: str, exe: str, params: dict[str, Any]) -> None:
        """Start package executable ``exe`` as child ``name`` with ``params``."""
        path = write_params_file(self.params_dir / f'{name}.yaml', params)
        self.sup.start(name, [find_executable(exe), '--ros-args', '--params-file', path])

    def wait_connected(self, extra: dict[str, tuple[int, int]] | None = None) -> None:
        """Wait until every topic of the stack has its publishers and subscribers."""
        t = self.ros.node.topics
        # the launcher node itself subscribes to the state and the episode events; the
        # policy node answers on command_stamped (command is for hand use); the sim and the
        # policy node both draw on markers
        needs = {t['state']: (1, 3), t['command_stamped']: (1, 2), t['command']: (0, 2),
                 t['reward']: (1, 1), t['event']: (1, 2), t['exemplar']: (1, 1),
                 t['markers']: (2, 1), **(extra or {})}
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
            answer = self.ros.trigger(self.sup, '/recorder/ready')
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
        the waiting state for the policy to answer; realtime starts stepping."""
        self.ros.node.last_new_state = time.monotonic()
        change = ({'mode': 'realtime'} if self.opts.mode == 'realtime'
                  else {'republish_period': REPUBLISH_S})
        self.ros.set_parameters(self.sup, sim_executable(self.opts.problem.model), change)

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
        checked again once finished (``check_recording``)."""
        try:
            self.sup.wait(lambda: not self.recording_gaps(ends), timeout=RECORDED_S,
                          what='the recording')
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


def offline_episode(policy: Any, delta: float) -> dict:
    """The policy's offline evaluation (``sapga eval --json``): return, delta*, steps."""
    from sapga_ros.evaluation.any_policy import run_policy_episode
    return run_policy_episode(policy, delta).summary()


def event_summary(event: dict) -> dict:
    """Return, delta*, steps of an episode end event (delta* inf as in ``sapga eval``)."""
    dstar = event.get('delta_star')
    return {'return': event.get('return'), 'delta_star': math.inf if dstar is None else dstar,
            'steps': event.get('step'), 'reached': event.get('event') == 'goal'}


def same_episode(ros_ep: dict, offline: dict) -> bool:
    """Exactly equal return, delta*, steps and goal."""
    return all(ros_ep[k] == offline[k] for k in ('return', 'delta_star', 'steps', 'reached'))


def episode_lines(ends: list[dict]) -> list[str]:
    lines = [f'{"episode":>7} {"end":<10} {"steps":>5} {"return":>12} {"delta*":>9}']
    for e in ends:
        s = event_summary(e)
        lines.append(f'{e.get("episode", "?"):>7} {e.get("event"):<10} {s["steps"]:>5} '
                     f'{s["return"]:>12.4f} {s["delta_star"]:>9.5f}')
    return lines


# the swingup launch -------------------------------------------------------------------------

@dataclass
class SwingupResult:
    """What a swingup launch produced."""

    episodes: list[dict]            # the simulator's end events
    recordings: list[Path]
    offline: dict | None            # lockstep: the offline evaluation of the policy file
    equal: bool | None              # lockstep: every episode equals it
    recording_error: str | None = None  # why the bag is not whole, if it is not


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f'expected an integer >= 1, got {text!r}')
    return value


def finite_number(low: float, strict: bool = False):
    """argparse type: a finite number >= low (> low if ``strict``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < low or (strict and value == low):
            raise argparse.ArgumentTypeError(f'expected a finite number '
                                             f'{">" if strict else ">="} {low:g}, got {text!r}')
        return value
    return parse


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='sapga launch swingup',
                                description='Run a policy file on the simulator and record '
                                            'the episodes to MCAP.')
    p.add_argument('--policy', required=True, metavar='FILE', help='policy file (SPEC 3.3)')
    p.add_argument('--out', required=True, metavar='DIR', help='directory of the recording')
    p.add_argument('--mode', choices=MODES, default='lockstep',
                   help='lockstep (default; equals sapga eval) or realtime')
    p.add_argument('--episodes', type=positive_int, default=1, metavar='N',
                   help='episodes (default 1)')
    p.add_argument('--problem', help="problem (default: the policy file's; must match it)")
    p.add_argument('--delta', type=finite_number(0.0), help=(
        "goal difficulty (default: the policy's training delta, else the problem's)"))
    p.add_argument('--real-time-factor', type=finite_number(0.0, strict=True), default=1.0,
                   metavar='F', help='realtime mode: sim time / wall time (default 1)')
    return p


def policy_delta(policy: Any, given: float | None) -> float:
    """``given``, else the policy's training delta, else the problem's default."""
    if given is not None:
        return float(given)
    meta = policy.meta.get('delta') if isinstance(policy.meta, dict) else None
    if isinstance(meta, (int, float)) and not isinstance(meta, bool) and \
            math.isfinite(meta) and meta >= 0:
        return float(meta)
    return float(policy.problem.default_delta)


def run_swingup(args: argparse.Namespace, sup: Supervisor) -> SwingupResult:
    """The launch itself, under ``sup`` (which stops the nodes whatever happens)."""
    from sapga_ros.exemplars.policy import load_policy
    problem = load_problem(args.problem) if args.problem else None
    policy = load_policy(Path(args.policy).resolve(), problem)   # checked before any start
    problem = policy.problem
    opts = StackOptions(problem, Path(args.out).resolve(), policy_delta(policy, args.delta),
                        args.episodes, args.mode, args.real_time_factor)
    sup.say(f'{problem.name}: policy {args.policy} ({len(policy)} exemplars), delta '
            f'{opts.delta}, {opts.episodes} episode(s) in {opts.mode} mode, recording to '
            f'{opts.out}')
    ros = LaunchRos(problem)
    try:
        with tempfile.TemporaryDirectory(prefix='sapga-launch-') as tmp:
            stack = DeployStack(sup, ros, opts, Path(tmp))
            stack.start()
            ros.set_parameters(sup, 'policy_node',
                               {'policy_file': str(Path(args.policy).resolve())})
            stack.start_sim()
            stack.wait_connected()
            stack.go()
            ends = stack.run_episodes()
            stack.wait_recorded(ends)
    finally:
        sup.stop()
        ros.close()
    offline = equal = None
    if opts.mode == 'lockstep':
        offline = offline_episode(policy, opts.delta)
        equal = all(same_episode(event_summary(e), offline) for e in ends)
    return SwingupResult(ends, stack.recordings(), offline, equal, stack.check_recording(ends))


def print_swingup(sup: Supervisor, result: SwingupResult) -> int:
    """Print the summary; 0, or 1 if a lockstep episode differs from the offline one."""
    lines = episode_lines(result.episodes)
    for path in result.recordings:
        lines.append(f'recording: {path}')
    if not result.recordings:
        lines.append("recording: none written (see the recorder's output)")
    if result.offline is not None:
        o = result.offline
        lines.append(f'offline evaluation (sapga eval): return {o["return"]:.4f}, delta* '
                     f'{o["delta_star"]:.5f}, steps {o["steps"]}: '
                     + ('every lockstep episode is equal' if result.equal
                        else 'DIFFERENT from the lockstep episodes'))
    if result.recording_error:
        lines.append(f'error: {result.recording_error}')
    sup.say('\n'.join(lines))
    return 0 if result.equal in (None, True) and not result.recording_error else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``sapga launch swingup ...``; the exit code (see ``run_launch``)."""
    return launch_main(argv, build_parser(), run_swingup, print_swingup)


if __name__ == '__main__':
    sys.exit(main())
