"""Policy node: an exemplar policy of any style behind the topic contract (SPEC 4).

Subscribes to the state (``sensor_msgs/JointState``), selects the action with the policy's
style through the same compiled selector and packing as ``Evaluator``
(``sapga_ros.evaluation.state_selector``), and answers it on ``command_stamped``
(``sensor_msgs/JointState`` stamped with the answered state's stamp, ``effort`` = the action
on the actuator joint: ``sim_nodes/ros/commands.py``), with the exemplar the selector
reported on ``exemplar_index`` (-1: none, e.g. a via-point policy heading for the best
state) and that exemplar's state drawn as a ghost on ``markers`` (namespace ``exemplar``).
Each distinct state stamp is answered once, so the lockstep sim's re-publishes are harmless.
A via-point policy starts its list again whenever the state is the problem's initial state
(every episode starts there).

Parameters:

================  ========  ============  ================================================
name              type      default       meaning
================  ========  ============  ================================================
problem           string    acrobot       msg_configs/<problem>.yaml (read-only)
policy_file       string    ''            a policy JSON file (SPEC 3.3), loaded at start;
                                          setting it loads that file or is refused
trainer_service   string    get_policy    the trainer's std_srvs/Trigger (read-only)
load_timeout      double    5.0           [s] wait for the trainer's answer at most
markers           bool      true          publish the exemplar ghost on ``markers``
qos_profile       string    reliable      ``reliable`` (the problem's ``ros.qos``) |
                                          ``sensor_data`` (best effort; read-only)
================  ========  ============  ================================================

Service ``load_policy`` (std_srvs/Trigger) fetches the policy from ``trainer_service``.  A
policy that fails validation is refused with the reason and the old one is kept; a good one
replaces the old one atomically (one reference assignment of an immutable
``PreparedPolicy``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Int32
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from sapga_ros.errors import ConfigError, SapgaError
from sim_nodes.ros.commands import StampedCommand
from sim_nodes.ros.common import (QOS_PROFILES, QUIET_PUBLISHER, THROTTLE_S, JointStateLayout,
                                  MessageError, run_node, stamp_ns, steady_clock, topic_names,
                                  topic_qos)
from sim_nodes.ros.markers import PendulumMarkers
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.exemplars.policy import ExemplarPolicy, load_policy, policy_from_json
from sim_nodes.problem import Problem, load_problem

POLL_S = 0.02  # [s] how often a pending load checks for the service and its deadline


@dataclass(frozen=True)
class PreparedPolicy:
    """A validated policy in the selector's layout; never modified once made."""

    policy: ExemplarPolicy
    selector: StateSelector  # packed as Evaluator.pack packs it (its scratch changes)
    source: str             # where it came from (file path or service name)

    @classmethod
    def of(cls, policy: ExemplarPolicy, source: str) -> PreparedPolicy:
        return cls(policy, StateSelector(policy), source)

    def __len__(self) -> int:
        return len(self.policy)


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None (files: see below)."""
    if name == 'load_timeout' and not (np.isfinite(value) and value > 0):
        return f'load_timeout: expected a finite number of seconds > 0, got {value}'
    if name == 'qos_profile' and value not in QOS_PROFILES:
        return f'qos_profile: expected one of {", ".join(QOS_PROFILES)}, got {value!r}'
    return None


class PolicyNode(Node):
    """Answers each state with the action its policy selects."""

    def __init__(self, node_name: str = 'policy_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        ro = ParameterDescriptor(read_only=True)
        name = self.declare_parameter('problem', 'acrobot', ro).value
        self.problem: Problem = load_problem(name)
        policy_file = self.declare_parameter('policy_file', '').value
        service = self.declare_parameter('trainer_service', 'get_policy', ro).value
        self.load_timeout = self.declare_parameter('load_timeout', 5.0).value
        self.markers = self.declare_parameter('markers', True).value
        self.qos_profile = self.declare_parameter('qos_profile', 'reliable', ro).value
        for key in ('load_timeout', 'qos_profile'):
            reason = check_setting(key, getattr(self, key))
            if reason:
                raise ConfigError(f'{self.get_name()}: parameter {reason}')

        p = self.problem
        self._layout = JointStateLayout(p)
        self._s = np.empty(p.dim)      # scratch: raw state
        self._s0 = p.initial_state
        self.active: PreparedPolicy | None = None
        self._staged: dict[str, PreparedPolicy] = {}
        self._last_stamp: int | None = None
        self.answered = 0              # states answered
        self.rejected = 0              # bad state messages skipped
        self.unanswered = 0            # states seen with no policy loaded

        topics = topic_names(p)
        qos = topic_qos(p, self.qos_profile)
        quiet = {'event_callbacks': QUIET_PUBLISHER}
        self._command_pub = self.create_publisher(JointState, topics['command_stamped'], qos,
                                                  **quiet)
        self._index_pub = self.create_publisher(Int32, topics['exemplar'], qos, **quiet)
        self._marker_pub = self.create_publisher(MarkerArray, topics['markers'], qos, **quiet)
        self._state_sub = self.create_subscription(JointState, topics['state'],
                                                   self._on_state, qos)
        # The load_policy coroutine stays in progress while it awaits the trainer.  In the
        # node's default (mutually exclusive) group it would keep the client's response and
        # the poll timer from running: a deadlock.  A reentrant group of their own lets one
        # executor thread run them while the coroutine waits.
        self._load_group = ReentrantCallbackGroup()
        self._client = self.create_client(Trigger, service, callback_group=self._load_group)
        self._load_srv = self.create_service(Trigger, 'load_policy', self._on_load_policy,
                                             callback_group=self._load_group)
        self._command = StampedCommand(p)
        self._index_msg = Int32()
        self._ghosts = PendulumMarkers(p)

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        if policy_file:
            try:
                self._install(PreparedPolicy.of(load_policy(policy_file, p), policy_file))
            except SapgaError as exc:
                self.get_logger().error(f'no policy loaded: {exc}')
        self.get_logger().info(f'{p.name} policy node; load_policy fetches from {service!r}')

    # selection ------------------------------------------------------------------------------

    def select(self, msg: JointState, prepared: PreparedPolicy) -> tuple[int, float]:
        """(exemplar index reported, action value) of ``prepared`` for the state in ``msg``.

        Raises ``MessageError`` for a malformed state message.
        """
        s = self._layout.from_msg(msg, self._s)
        selector = prepared.selector
        if selector.stateful and np.array_equal(s, self._s0):
            selector.reset()  # an episode starts
        return selector.select(s)

    def _on_state(self, msg: JointState) -> None:
        stamp = stamp_ns(msg)
        if stamp == self._last_stamp:
            return  # answered already: a lockstep re-publish
        prepared = self.active  # one read: a swap during this callback cannot mix policies
        if prepared is None:
            self.unanswered += 1
            self.get_logger().warning('no policy loaded: not answering the state (set '
                                      'policy_file or call load_policy)',
                                      throttle_duration_sec=THROTTLE_S)
            return
        try:
            j, action = self.select(msg, prepared)
        except MessageError as exc:
            self.rejected += 1
            self.get_logger().warning(f'skipping state message: {exc}',
                                      throttle_duration_sec=THROTTLE_S)
            return
        self._last_stamp = stamp
        self.answered += 1
        self._command_pub.publish(self._command.fill(action, stamp))
        self._index_msg.data = int(j)
        self._index_pub.publish(self._index_msg)
        if self.markers:
            ghost = self._ghosts.exemplar(prepared.policy.states[j] if j >= 0 else None, stamp)
            if ghost is not None:
                self._marker_pub.publish(ghost)

    # policies -------------------------------------------------------------------------------

    def _install(self, prepared: PreparedPolicy) -> str:
        self.active = prepared  # the atomic swap
        meta = prepared.policy.meta
        value = f', value {meta["value"]}' if 'value' in meta else ''
        text = (f'policy from {prepared.source}: {len(prepared)} exemplars '
                f'({prepared.policy.style}){value}')
        self.get_logger().info(text)
        return text

    def install_json(self, text: str, source: str) -> tuple[bool, str]:
        """Validate a policy document and swap it in; (success, message)."""
        try:
            policy = policy_from_json(text, problem=self.problem, source=source)
        except SapgaError as exc:
            self.get_logger().error(f'policy refused, keeping the current one: {exc}')
            return False, str(exc)
        return True, self._install(PreparedPolicy.of(policy, source))

    async def _on_load_policy(self, request: Trigger.Request, response: Trigger.Response
                              ) -> Trigger.Response:
        text, error = await self._fetch_policy_text()
        if error is None:
            response.success, response.message = self.install_json(
                text, f'service {self._client.srv_name}')
        else:
            self.get_logger().error(f'load_policy: {error}; keeping the current policy')
            response.success, response.message = False, error
        return response

    async def _fetch_policy_text(self) -> tuple[str, str | None]:
        """Call the trainer's Trigger without blocking the executor: (text, error or None)."""
        done = Future()
        deadline = time.monotonic() + self.load_timeout
        call: list[Future] = []

        def finish(result: tuple[str, str | None]) -> None:
            if not done.done():
                done.set_result(result)

        def answered(future: Future) -> None:
            try:
                reply = future.result()
            except Exception as exc:  # noqa: BLE001 - reported to the caller
                finish(('', f'{self._client.srv_name} failed: {exc}'))
                return
            if reply is None or not reply.success:
                why = reply.message[:300] if reply is not None else 'no response'
                finish(('', f'{self._client.srv_name} refused: {why}'))
            else:
                finish((reply.message, None))

        def poll() -> None:
            if done.done():
                return
            if not call and self._client.service_is_ready():
                call.append(self._client.call_async(Trigger.Request()))
                call[0].add_done_callback(answered)
            elif time.monotonic() >= deadline:
                if call:
                    self._client.remove_pending_request(call[0])
                what = 'did not answer' if call else 'is not available'
                finish(('', f'trainer service {self._client.srv_name} {what} within '
                            f'{self.load_timeout} s'))

        timer = self.create_timer(POLL_S, poll, callback_group=self._load_group,
                                  clock=steady_clock())
        poll()
        try:
            return await done
        finally:
            self.destroy_timer(timer)

    # parameters -----------------------------------------------------------------------------

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            reason = check_setting(param.name, param.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            if param.name == 'policy_file' and param.value:
                try:
                    policy = load_policy(param.value, self.problem)
                except SapgaError as exc:
                    self.get_logger().error(f'policy refused, keeping the current one: {exc}')
                    return SetParametersResult(successful=False, reason=str(exc))
                self._staged[param.value] = PreparedPolicy.of(policy, param.value)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for param in params:
            if param.name in ('load_timeout', 'markers'):
                setattr(self, param.name, param.value)
            elif param.name == 'policy_file' and param.value in self._staged:
                self._install(self._staged.pop(param.value))
        self._staged.clear()


def main(args: list[str] | None = None) -> int:
    """``ros2 run sapga_ros policy_node``."""
    return run_node(lambda: PolicyNode(), args)


if __name__ == '__main__':
    raise SystemExit(main())
