"""Simulator node: one problem model behind the ROS 2 topic contract.

``SimNode`` wraps the same compiled ``mdp_step`` and ``goal_delta`` the batch evaluator
uses, so a lockstep episode is bit-identical to ``Evaluator.episode`` (docs/ros_interface.md).
Its parameters are ``sim_settings.py``'s (validated on every change; ``problem`` and
``qos_profile`` are read-only); commands are checked as ``commands.py`` says, markers drawn
as ``markers.py`` says.  Service ``~/reset`` (``/<node>/reset``, std_srvs/Trigger) starts a
new episode; ``/diagnostics`` reports the node's state and counters once a second.
``engine:=mujoco`` steps the MuJoCo robot of ``mujoco_engine.py`` instead of the kernel: the
state is published as that robot's joints, and its ``std_msgs/Float64MultiArray`` effort
command is taken as ``command`` is; every command input then carries the robot's effort (its
joint names, its direction).

Time: every published new state is one tick (``dt * substeps``, 0.05 s for the pendulums)
of sim time later than the previous one (an MDP step, or the start of an episode), so
stamps are distinct and monotonic.
In lockstep the command answering an episode's final state starts the next episode (with
auto_reset) instead of stepping, so each state gets exactly one command; a stamped command
steps only the state it answers.

Start: the first episode waits for the recorder named by ``wait_for_recorder``
(``recorder_gate.py``).  In realtime (``wait_for_policy``) its first state is then
re-published until a command answers it (``answer_wait.py``), or the node stops after
``policy_timeout`` with one line saying what the graph shows; only then is the step timer
made.  The step, goal test and drawing are compiled (or
loaded from the cache) in the constructor, so the first tick comes one period after that
answer, and a tick that comes late puts the next one a whole period off (``CATCH_UP``): no
stall, and no ticks fired back to back to catch up.  In realtime a state that no command
answered before the next tick counts as late (``late_commands``).

The file is about 400 lines: one node's episode loop with its ROS wiring; what stands alone
is split out (``commands``, ``markers``, ``dropped``, ``recorder_gate``, ``answer_wait``,
``diagnostics``).
"""
from __future__ import annotations

import json
import math
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from sim_nodes.disturbance import Plant, load_disturbance
from sim_nodes.draws import HELD_OUT
from sim_nodes.goal import goal_arrays, goal_delta, hold_measures
from sim_nodes.models import MODELS, model_module
from sim_nodes.models.registry import GENERIC_SIM, sim_executable
from sim_nodes.problem import load_problem
from sim_nodes.ros.answer_wait import AnswerWait
from sim_nodes.ros.commands import CommandCheck, StampedCommand
from sim_nodes.ros.common import (CLOCK_QOS, EVENT_QOS, QUIET_PUBLISHER, JointStateLayout,
                                  MessageError, check_topic_types, run_node, steady_clock,
                                  topic_names, topic_qos)
from sim_nodes.ros.diagnostics import OK, WARN, NodeDiagnostics, Report
from sim_nodes.ros.dropped import DropCounter
from sim_nodes.ros.executors import node_executor, with_info
from sim_nodes.ros.guarded import GuardedNode
from sim_nodes.ros.marker_bytes import MarkerBytes
from sim_nodes.ros.markers import PendulumMarkers
from sim_nodes.ros.mujoco_engine import MujocoEngine
from sim_nodes.ros.params import declare
from sim_nodes.ros.recorder_gate import RecorderGate
from sim_nodes.ros.sim_settings import (MODES, SimSettings, check_setting,  # noqa: F401
                                        declare_settings, engine_parameters, read_settings,
                                        sim_parameters)


CATCH_UP = 0.6     # realtime: a next tick due sooner than this many periods is put off


def _json_number(x: float) -> float | None:
    """JSON has no infinity: non-finite numbers become null."""
    return x if math.isfinite(x) else None


class SimNode(GuardedNode):
    """Simulates one problem; publishes its state, reward, markers and episode events."""

    def __init__(self, default_problem: str = 'acrobot', node_name: str = 'sim',
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        name = declare(self, sim_parameters(default_problem)[:1])['problem']
        self.problem = problem = load_problem(name)
        self._mdp_step = model_module(problem.model).mdp_step
        self._best, self._inv_scale, self._fixed = goal_arrays(problem)
        self._is_angle = problem.is_angle
        self._s0 = problem.initial_state
        self._tick_ns = round(problem.dt * problem.substeps * 1e9)  # sim time per tick
        self._layout = JointStateLayout(problem)
        self._stamped = StampedCommand(problem)
        engine = declare(self, engine_parameters())
        self._robot = MujocoEngine(problem) if engine['engine'] == 'mujoco' else None
        if self._robot is not None:     # the MuJoCo robot: its joints, its effort commands
            self._mdp_step = self._robot.mdp_step
            self._layout = self._robot
            self._stamped.joint = self._robot.actuator_joint
        self._markers = PendulumMarkers(problem)
        self._marker_bytes = MarkerBytes()   # serialized by patching (marker_bytes.py)
        self.qos_profile = declare_settings(self, problem)
        self.settings = read_settings(self)
        self._plant = Plant(problem, load_disturbance(self.get_parameter('disturbance').value))
        self._draw_seed = self.get_parameter('disturbance_seed').value
        self.commands = CommandCheck(float(np.max(np.abs(problem.action_values))),
                                     self.get_logger())

        topics = topic_names(problem)
        check_topic_types(self, [
            *((f'ros.topics.{role}', topics[role], kind) for role, kind in (
                ('state', JointState), ('reward', Float64), ('markers', MarkerArray),
                ('event', String), ('command', Float64), ('command_stamped', JointState))),
            *((('effort_topic', engine['effort_topic'], Float64MultiArray),)
              if self._robot is not None else ()),
            ('the clock', '/clock', Clock), ('the diagnostics', '/diagnostics', DiagnosticArray)])
        qos = topic_qos(problem, self.qos_profile)
        quiet = {'event_callbacks': QUIET_PUBLISHER}
        self._state_pub = self.create_publisher(JointState, topics['state'], qos, **quiet)
        self._reward_pub = self.create_publisher(Float64, topics['reward'], qos, **quiet)
        self._marker_pub = self.create_publisher(MarkerArray, topics['markers'], qos, **quiet)
        self._event_pub = self.create_publisher(String, topics['event'], EVENT_QOS, **quiet)
        self._clock_pub = None         # only while publish_clock is true (_configure_clock)
        self._command_sub = self.create_subscription(Float64, topics['command'],
                                                     with_info(self._on_command), qos)
        self._stamped_sub = self.create_subscription(JointState, topics['command_stamped'],
                                                     with_info(self._on_stamped_command), qos)
        subs = [self._command_sub, self._stamped_sub]
        if self._robot is not None:
            self._effort_sub = self.create_subscription(
                Float64MultiArray, engine['effort_topic'], with_info(self._on_effort), qos)
            subs.append(self._effort_sub)
        self.dropped = {sub.topic_name: DropCounter(self.get_logger(), sub.topic_name,
                                                    sub.get_publisher_count, qos.depth)
                        for sub in subs}
        self._reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._step_timer = None
        self._republish_timer = None

        # episode state
        self._s = self._s0.copy()
        self._seen = self._s0.copy()   # what the policy is told: the state + sensor noise
        self._state_msg = self._layout.new_msg()
        self._reward_msg = Float64()
        self._clock_msg = Clock()
        self._marker_data: bytes | None = None   # the markers of the state last published
        self._tick = -1                # sim time of the last published state, in ticks
        self._episode = 0              # episodes started
        self._step = 0                 # MDP steps in this episode
        self._return = 0.0
        self._delta_star = math.inf
        self._contact_below = problem.contact_below  # a reward below: an end-stop contact
        self._hold = [0, 0, 0]         # first step in S_delta (0: none), steps held, contacts
        self._effort = 0.0             # applied in the step that produced the state
        self._command = 0.0            # realtime: held command
        self._answered = False         # realtime: the current state has its command
        self._late_before = 0          # late commands before this episode
        self._running = False          # an episode is in progress
        self._restart_pending = False  # the next tick starts a new episode
        self.total_steps = 0           # MDP steps simulated by this node

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._configure_clock()
        self._warm_up()
        self._wait: AnswerWait | None = None    # realtime start (answer_wait.py)
        self.diagnostics = NodeDiagnostics(self, 'simulator', problem.name, self._report)
        self._gate = RecorderGate(self, self._first_episode)  # the first episode
        s = self.settings
        self.get_logger().info(
            f'{problem.name} sim ({engine["engine"]}): mode {s.mode}, delta {s.delta}, '
            f'n_step {s.n_step}, actuator limit {self.commands.limit}, QoS {self.qos_profile}')

    # parameters -------------------------------------------------------------------------

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            reason = check_setting(param.name, param.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        old, self.settings = self.settings, read_settings(self)
        if (old.mode, old.real_time_factor, old.republish_period) != (
                self.settings.mode, self.settings.real_time_factor,
                self.settings.republish_period):
            self._configure_timers()
        if self.settings.mode != old.mode:
            self.get_logger().info(f'mode {self.settings.mode}')
        if self.settings.publish_clock != old.publish_clock:
            self._configure_clock()

    def _configure_clock(self) -> None:
        """A /clock publisher exactly while ``publish_clock`` is true (a simulator that does
        not publish the clock is no /clock publisher on the graph)."""
        if self.settings.publish_clock and self._clock_pub is None:
            self._clock_pub = self.create_publisher(Clock, '/clock', CLOCK_QOS,
                                                    event_callbacks=QUIET_PUBLISHER)
        elif not self.settings.publish_clock and self._clock_pub is not None:
            self.destroy_publisher(self._clock_pub)
            self._clock_pub = None

    def _configure_timers(self) -> None:
        for timer in (self._step_timer, self._republish_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._step_timer = self._republish_timer = None
        s = self.settings
        period = self._tick_ns * 1e-9 / s.real_time_factor
        if self._wait is not None:
            return                      # realtime start: the first answer makes them
        if s.mode == 'realtime':
            self._step_timer = self.create_timer(period, self._on_step_timer,
                                                 clock=steady_clock())
            return
        if self.qos_profile == 'sensor_data':
            self.get_logger().warning('lockstep over best-effort QoS (sensor_data): a lost '
                                      'command stalls the episode')
        if s.republish_period > 0:
            self._republish_timer = self.create_timer(s.republish_period, self._on_republish,
                                                      clock=steady_clock())

    # callbacks ----------------------------------------------------------------------------

    def _on_command(self, msg: Float64, info: dict) -> None:
        """Hand-use command (no stamp): lockstep takes it as the current state's answer."""
        self.dropped[self._command_sub.topic_name].seen(info)
        self._take_unstamped(self._robot.action([msg.data]) if self._robot else msg.data)

    def _on_effort(self, msg: Float64MultiArray, info: dict) -> None:
        """engine mujoco: the robot's effort command (no stamp, as ``command``)."""
        self.dropped[self._effort_sub.topic_name].seen(info)
        try:
            value = self._robot.action(msg.data)
        except MessageError as exc:
            self.commands.reject(str(exc))
            return
        self._take_unstamped(value)

    def _take_unstamped(self, value: float) -> None:
        value = self.commands.value(value)
        if value is None:
            return
        if self.settings.mode == 'lockstep':
            self._advance(value)
        else:
            self._answered = True       # no stamp: the answer to the current state
            self._command = value

    def _on_stamped_command(self, msg: JointState, info: dict) -> None:
        """The policy node's answer to the state stamped ``header.stamp``."""
        self.dropped[self._stamped_sub.topic_name].seen(info)
        try:
            answered, value = self._stamped.read(msg)
            value = self._robot.action([value]) if self._robot else value
        except MessageError as exc:
            self.commands.reject(f'stamped command: {exc}')
            return
        value = self.commands.value(value)
        if value is None:
            return
        current = self._tick * self._tick_ns
        if self.settings.mode == 'lockstep':
            if answered != current:
                self.commands.count_late(answered, current)
                return
            self._advance(value)
        else:
            # one answering an older state is applied all the same (the freshest the policy
            # said); that state was counted unanswered when its tick passed
            self._answered = self._answered or answered == current
            self._command = value

    def _on_step_timer(self) -> None:
        if self._running and not self._answered:
            self.commands.count_unanswered(self._tick * self._tick_ns)
        self._advance(self._command)
        timer = self._step_timer
        if timer is not None and timer.time_until_next_call() < CATCH_UP * timer.timer_period_ns:
            timer.reset()   # this tick came late: the next one a whole period from now

    def _on_republish(self) -> None:
        if self._tick >= 0:             # a state was published (the recorder gate is open)
            self._state_pub.publish(self._state_msg)
            if self._marker_data is not None:
                self._marker_pub.publish(self._marker_data)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        if self._running:
            self._publish_event('reset', self._delta_of_state())
        self._start_episode()
        response.success = True
        response.message = f'episode {self._episode} started'
        return response

    # the start ------------------------------------------------------------------------------

    def _warm_up(self) -> None:
        """Run the step, the goal test and the drawing once on scratch data, so that their
        compilation (or cache load) happens now, not in the first ticks of a run."""
        s = self._s0.copy()
        self._mdp_step(s, 0.0, self._plant.params)
        goal_delta(s, self._best, self._inv_scale, self._fixed, self._is_angle)
        self._markers.state_bytes(s, 0, self.settings.delta, self._marker_bytes)
        self._layout.fill(self._layout.new_msg(), s, 0.0, 0)

    def _first_episode(self) -> None:
        """The recorder is ready: start the first episode.  Realtime ticks count from the
        policy's first answer (``wait_for_policy``: ``answer_wait.py``) or from now."""
        self._start_episode()
        if self.settings.mode == 'realtime' and self.get_parameter('wait_for_policy').value:
            self._wait = AnswerWait(
                self, lambda: self._answered, lambda: self._state_pub.publish(self._state_msg),
                self._answered_first, (self._state_pub.topic_name,
                                       self._stamped_sub.topic_name),
                self.get_parameter('policy_timeout').value)
        else:
            self._configure_timers()

    def _answered_first(self) -> None:
        self._wait = None
        self._configure_timers()

    def _report(self) -> Report:
        """The node's /diagnostics: what it is doing, its counters."""
        s, c = self.settings, self.commands
        if not self._gate.open:
            level, message = WARN, f'waiting for recorder {self._gate.recorder!r}'
        elif self._wait is not None:
            level, message = WARN, 'waiting for a command answering the first state'
        else:
            what = 'running' if self._running else 'between episodes'
            level, message = OK, f'{s.mode}: episode {self._episode} {what}, step {self._step}'
        dropped = sum(d.count for d in self.dropped.values())
        return level, message, {
            'mode': s.mode, 'episode': self._episode, 'step': self._step,
            'total_steps': self.total_steps, 'sim_time': self._tick * self._tick_ns / 1e9,
            'delta': float(s.delta), 'real_time_factor': float(s.real_time_factor),
            'late_commands': c.late, 'ignored_commands': c.ignored,
            'clamped_commands': c.clamped, 'dropped_commands': dropped}

    # the episode ----------------------------------------------------------------------------

    def _advance(self, action: float) -> None:
        """One tick: an MDP step, or the start of the next episode after one ended."""
        if self._running:
            self._step_once(action)
        elif self._restart_pending:
            self._start_episode()

    def _step_once(self, action: float) -> None:
        """Evaluator's episode loop body: step, count the reward, then test the goal."""
        action = self._plant.command(action)    # late, gain error (none: as given)
        self._plant.push(self._s)
        reward = self._mdp_step(self._s, action, self._plant.params)
        self._plant.advance()
        self._seen = self._plant.observe(self._s)
        self._step += 1
        self.total_steps += 1
        self._return += reward
        d = self._delta_of_state()
        if d < self._delta_star:
            self._delta_star = d
        hit = reward < self._contact_below
        self._hold[2] += hit
        inside = d <= self.settings.delta
        if inside:
            self._hold[0] = self._hold[0] or self._step
            self._hold[1] += 1
            if not self.problem.ends_in_goal:       # the hold task: bonus, no end
                self._return += self.problem.hold_bonus
        self._effort = action
        self._tick += 1
        self._reward_msg.data = reward
        self._reward_pub.publish(self._reward_msg)
        self._publish_state()
        if inside and self.problem.ends_in_goal:
            self._end_episode('goal', d)
        elif hit and self.problem.end_stop == 'fail':   # charged for the steps not run
            self._return += (self.settings.n_step - self._step) * self.problem.fail_charge
            self._end_episode('end_stop', d)
        elif self._step >= self.settings.n_step:
            self._end_episode('step_limit', d)

    def _start_episode(self) -> None:
        self._plant.n_step = self.settings.n_step
        self._s[:] = self._plant.reset((self._draw_seed, 0, HELD_OUT, self._episode))
        self._seen = self._plant.observe(self._s)
        if self._robot is not None:     # the MuJoCo robot starts where the plant does,
            self._robot.reset(self._s, self._plant.params)   # with its model error
        self._episode += 1
        self._step = 0
        self._return = 0.0
        self._hold = [0, 0, 0]
        self._effort = 0.0
        self._late_before = self.commands.late
        self._delta_star = d = self._delta_of_state()
        self._running = True
        self._restart_pending = False
        self._tick += 1
        self._publish_event('start', d)
        self._publish_state()

    def _end_episode(self, event: str, d: float) -> None:
        self._running = False
        s = self.settings
        self._restart_pending = s.auto_reset and (
            s.max_episodes == 0 or self._episode < s.max_episodes)
        self._publish_event(event, d)

    def _delta_of_state(self) -> float:
        return goal_delta(self._s, self._best, self._inv_scale, self._fixed, self._is_angle)

    # publishing ---------------------------------------------------------------------------

    def _publish_state(self) -> None:
        """Publish the state (its markers and /clock) at the current tick."""
        ns = self._tick * self._tick_ns
        self._answered = False
        self._layout.fill(self._state_msg, self._seen, self._effort, ns)
        self._state_pub.publish(self._state_msg)
        s = self.settings
        self._marker_data = self._markers.state_bytes(self._s, ns, s.delta,
                                                      self._marker_bytes) if s.markers else None
        if self._marker_data is not None:
            self._marker_pub.publish(self._marker_data)
        if self._clock_pub is not None:
            self._clock_msg.clock = self._state_msg.header.stamp
            self._clock_pub.publish(self._clock_msg)

    def _publish_event(self, event: str, d: float) -> None:
        doc = {'event': event, 'episode': self._episode, 'step': self._step,
               'return': _json_number(self._return), 'delta': _json_number(d),
               'delta_star': _json_number(self._delta_star),
               'goal_delta': self.settings.delta,
               'time': self._tick * self._tick_ns / 1e9,   # sim time of the state [s]
               'late_commands': self.commands.late - self._late_before,
               'engine': 'kernel' if self._robot is None else 'mujoco',
               **hold_measures(*self._hold[:2], self._step, self._hold[2])}
        self._event_pub.publish(String(data=json.dumps(doc, allow_nan=False)))


def main(args: list[str] | None = None, problem: str = 'acrobot',
         node_name: str = GENERIC_SIM) -> int:
    """``ros2 run sapga_ros sim_node``: a simulator node of any problem (``problem`` is the
    default of the ``problem`` parameter)."""
    return run_node(lambda: SimNode(default_problem=problem, node_name=node_name), args,
                    executor=node_executor, parameters=lambda: sim_parameters(problem),
                    name=node_name)


def model_main(model: str) -> Callable[[list[str] | None], int]:
    """``main`` of ``ros2 run sapga_ros <model>_sim``: node ``<model>_sim``, problem
    ``<model>`` by default (``pdip_sim -p problem:=pdip_single`` for the single pole)."""
    name = sim_executable(model)
    return lambda args=None: main(args, model, name)


# the console scripts of setup.py: ``<model>_sim = sim_nodes.ros.sim_node:mains.<model>_sim``
mains = SimpleNamespace(**{sim_executable(m): model_main(m) for m in MODELS})


if __name__ == '__main__':
    raise SystemExit(main())
