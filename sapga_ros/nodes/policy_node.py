"""Policy node: an exemplar policy of any style behind the topic contract.

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

Parameters (``policy_params.py``; ``policy_node --help`` prints them with their ranges):
``problem``, ``policy_file``, ``trainer_service``, ``load_timeout``, ``delay`` (every plain
policy run as designed for that actuation delay), ``markers``, ``qos_profile``, and the
mapping onto a robot that is not ours (``joint_mapping.py``): its
joint names, angle offsets and directions, velocities from finite differences when its
``JointState`` has none, and the command as a ``std_msgs/Float64MultiArray`` effort array;
``replan`` and its settings run decision-time planning on top of the policy instead of its
selector (``sapga_ros.evaluation.replan``: the plan of the policy's own episode, improved on
the nominal model at every state; exemplar index -1).

A ``policy_file`` given at start is loaded at once, whatever its size; one that cannot be used
stops the node with one line naming the file (exit 2).  Service ``~/load_policy``
(``/policy_node/load_policy``, std_srvs/Trigger) fetches the policy from ``trainer_service``.  A
policy that fails validation is refused with the reason and the old one is kept; a good one
replaces the old one atomically (one reference assignment of an immutable
``PreparedPolicy``).  Parsing and packing happen in a worker thread (``policy_loader.py``), so
states are answered with the old policy meanwhile: always for ``load_policy`` (it answers
once the policy is in), and for a ``policy_file`` larger than ``SYNC_BYTES``.  A smaller file
is loaded at once, so setting ``policy_file`` is refused with the reason; a larger one is
accepted at once, swapped in when ready, and if it fails, the error is logged and
``policy_file`` goes back to the file of the policy in use.  States that arrive faster than
they are answered are dropped by the subscription's queue: counted in ``dropped.count``
with a throttled warning (``sim_nodes/ros/dropped.py``).  Just over 300 lines: the node's
callbacks in one place; loading, mapping and parameters are their own modules.
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.parameter import Parameter
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Int32
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from sapga_ros.errors import PolicyFileError, SapgaError
from sapga_ros.policies.classical import is_classical, run_ahead
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import load_policy, policy_from_json
from sapga_ros.policies.jsonfile import MAX_POLICY_BYTES
from sapga_ros.io.bounded import open_regular
from sapga_ros.nodes.joint_mapping import JointMapping, RobotState
from sapga_ros.nodes.policy_loader import LoadResult, PolicyLoader, PreparedPolicy, fetch_text
from sapga_ros.evaluation.replan_settings import ReplanSettings, check_plannable
from sapga_ros.evaluation.state_selector import StateSelector
from sim_nodes.params import build
from sapga_ros.nodes.policy_params import PARAMETERS, check_setting
from sim_nodes.problem import Problem, load_problem
from sim_nodes.ros.commands import StampedCommand
from sim_nodes.ros.common import (QUIET_PUBLISHER, THROTTLE_S, JointStateLayout, MessageError,
                                  check_topic_types, run_node, stamp_ns, topic_names, topic_qos)
from sim_nodes.ros.diagnostics import OK, WARN, NodeDiagnostics, Report
from sim_nodes.ros.dropped import DropCounter
from sim_nodes.ros.executors import node_executor, with_info
from sim_nodes.ros.guarded import GuardedNode
from sim_nodes.ros.marker_bytes import MarkerBytes
from sim_nodes.ros.markers import PendulumMarkers
from sim_nodes.ros.params import declare

SYNC_BYTES = 256 * 1024  # [bytes] policy files up to this size load at once (~35 ms)


def policy_file_size(path: str) -> int:
    """The size of policy file ``path``, checked as ``load_policy`` checks it, unread."""
    try:
        with open_regular(path) as f:
            size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise PolicyFileError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    if size > MAX_POLICY_BYTES:
        raise PolicyFileError(f'{path}: larger than the {MAX_POLICY_BYTES // (1024 * 1024)} '
                              'MB limit')
    return size


class PolicyNode(GuardedNode):
    """Answers each state with the action its policy selects."""

    def __init__(self, node_name: str = 'policy_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        values = declare(self, PARAMETERS)
        self.problem: Problem = load_problem(values['problem'])
        policy_file, service = values['policy_file'], values['trainer_service']
        self.load_timeout = values['load_timeout']
        self.delay = values['delay']         # run plain exemplar policies as designed for it
        self.replan = values['replan']       # or plan on each policy's episode, that delay ahead
        if self.replan:
            check_plannable(self.problem)
            from sapga_ros.evaluation.replan import PlanningSelector
            settings = build(ReplanSettings, lambda name: values[name])
            self.make_selector = lambda policy: PlanningSelector(policy, settings, self.delay)
        else:
            self.make_selector = StateSelector
        self.markers = values['markers']
        self.qos_profile = values['qos_profile']

        p = self.problem
        self._layout = JointStateLayout(p)
        self.mapping = JointMapping.of(p, values)
        self.robot = RobotState(self.mapping)    # the robot's JointState as the problem's
        self._s = np.empty(p.dim)      # scratch: raw state
        self._s0 = p.initial_state
        self.active: PreparedPolicy | None = None
        self._staged: dict[str, PreparedPolicy] = {}
        self._loader = PolicyLoader(self)
        self._file_in_use = ''         # policy_file of the policy in use ('' none / service)
        self._reverting: str | None = None
        self._last_stamp: int | None = None
        self.answered = 0              # states answered
        self.rejected = 0              # bad state messages skipped
        self.unanswered = 0            # states seen with no policy loaded

        topics = topic_names(p)
        check_topic_types(self, [
            *((f'ros.topics.{role}', topics[role], kind) for role, kind in (
                ('command_stamped', JointState), ('exemplar', Int32),
                ('markers', MarkerArray), ('state', JointState))),
            *((('effort_topic', values['effort_topic'], Float64MultiArray),)
              if self.mapping.command_output == 'effort_array' else ()),
            ('the diagnostics', '/diagnostics', DiagnosticArray)])
        qos = topic_qos(p, self.qos_profile)
        quiet = {'event_callbacks': QUIET_PUBLISHER}
        self._command_pub = self.create_publisher(JointState, topics['command_stamped'], qos,
                                                  **quiet)
        self._effort_pub = None
        if self.mapping.command_output == 'effort_array':
            self._effort_pub = self.create_publisher(Float64MultiArray, values['effort_topic'],
                                                     qos, **quiet)
            self._effort_msg = Float64MultiArray(data=[0.0] * self.mapping.effort_size)
        self._index_pub = self.create_publisher(Int32, topics['exemplar'], qos, **quiet)
        self._marker_pub = self.create_publisher(MarkerArray, topics['markers'], qos, **quiet)
        self._state_sub = self.create_subscription(JointState, topics['state'],
                                                   with_info(self._on_state), qos)
        self.dropped = DropCounter(self.get_logger(), self._state_sub.topic_name,
                                   self._state_sub.get_publisher_count, qos.depth)
        # The load_policy coroutine stays in progress while it awaits the trainer.  In the
        # node's default (mutually exclusive) group it would keep the client's response and
        # the poll timer from running: a deadlock.  A reentrant group of their own lets one
        # executor thread run them while the coroutine waits.
        self._load_group = ReentrantCallbackGroup()
        self._client = self.create_client(Trigger, service, callback_group=self._load_group)
        self._load_srv = self.create_service(Trigger, '~/load_policy', self._on_load_policy,
                                             callback_group=self._load_group)
        self._command = StampedCommand(p)
        self._command.msg.name = [self.mapping.robot_joints[self.mapping.actuated]]
        self._index_msg = Int32()
        self._ghosts = PendulumMarkers(p)
        self._ghost_bytes = MarkerBytes()    # serialized by patching (marker_bytes.py)

        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.diagnostics = NodeDiagnostics(self, 'policy', p.name, self._report)
        if policy_file:
            # At start-up nothing waits for an answer: load at once, whatever the size, and a
            # file that cannot be used is a user error (PolicyFileError: one line, exit 2).
            self._install(PreparedPolicy.of(self._read(policy_file), policy_file,
                                            self.make_selector))
            self._file_in_use = policy_file
        self.get_logger().info(f'{p.name} policy node; load_policy fetches from {service!r}')
        if not self.mapping.identity or self._effort_pub is not None:
            self.get_logger().info(f'robot joints: {self.mapping.describe()}; commands: '
                                   f'{self.mapping.command_output}')

    # selection ------------------------------------------------------------------------------

    def select(self, msg: JointState, prepared: PreparedPolicy) -> tuple[int, float]:
        """(exemplar index reported, action value) of ``prepared`` for the state in ``msg``.

        Raises ``MessageError`` for a malformed state message.
        """
        s = self.robot.read(msg, self._s)
        selector = prepared.selector
        if selector.stateful and np.array_equal(s, self._s0):
            selector.reset()  # an episode starts
        return selector.select(s)

    def _on_state(self, msg: JointState, info: dict) -> None:
        self.dropped.seen(info)
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
        self._publish_command(action, stamp)
        self._index_msg.data = int(j)
        self._index_pub.publish(self._index_msg)
        if self.markers:
            ghost = self._ghosts.exemplar_bytes(prepared.policy.states[j] if j >= 0 else None,
                                                stamp, self._ghost_bytes)
            if ghost is not None:
                self._marker_pub.publish(ghost)

    def _report(self) -> Report:
        """The node's /diagnostics: the policy in use and the node's counters."""
        prepared = self.active
        values = {'policy': prepared.source if prepared is not None else 'none',
                  'exemplars': len(prepared) if prepared is not None else 0,
                  'style': prepared.policy.style if prepared is not None else '',
                  'loading': self.loading or '', 'answered': self.answered,
                  'unanswered': self.unanswered, 'rejected': self.rejected,
                  'dropped': self.dropped.count}
        if prepared is None:
            return WARN, 'no policy loaded: states are not answered', values
        return OK, f'{len(prepared)} exemplars from {prepared.source}'[:300], values

    def _publish_command(self, action: float, stamp: int) -> None:
        """The action as the robot takes it: stamped, or the effort array."""
        effort = self.mapping.effort(action)
        if self._effort_pub is None:
            self._command_pub.publish(self._command.fill(effort, stamp))
            return
        self._effort_msg.data[self.mapping.effort_index] = effort
        self._effort_pub.publish(self._effort_msg)

    # policies -------------------------------------------------------------------------------

    def _install(self, prepared: PreparedPolicy) -> str:
        self.active = prepared  # the atomic swap
        meta = prepared.policy.meta
        value = f', value {meta["value"]}' if 'value' in meta else ''
        what = ('the classical controller (LQR + energy swing-up)'
                if is_classical(prepared.policy) else
                f'{len(prepared)} exemplars ({prepared.policy.style})')
        text = f'policy from {prepared.source}: {what}{value}'
        if self.replan:
            text += ', re-planned as it runs'
        self.get_logger().info(text)
        return text

    @property
    def loading(self) -> str | None:
        """The source of the policy being prepared in the background, if any."""
        return self._loader.loading

    def _read(self, path: str) -> ExemplarPolicy:
        """Policy file ``path`` as this node runs it."""
        return self._as_run(load_policy(path, self.problem), path)

    def _as_run(self, policy: ExemplarPolicy, source: str) -> ExemplarPolicy:
        """``policy`` (from ``source``) designed for the node's ``delay``, if set (with
        ``replan`` the planner predicts that far ahead: the policy runs as it is)."""
        return policy if self.replan else run_ahead(policy, self.delay, source)

    def _load_file(self, path: str) -> None:
        """Load policy file ``path`` in a worker thread; swap it in when it is ready."""
        self.get_logger().info(f'loading {path} in the background; the policy in use '
                               'answers meanwhile')
        self._loader.start(path, lambda: self._read(path), self._file_loaded)

    def _file_loaded(self, result: LoadResult) -> None:
        if result.prepared is not None:
            self._install(result.prepared)
            self._file_in_use = result.source
            return
        if not result.current:
            return
        self.get_logger().error(f'policy refused, keeping the current one: {result.error}')
        if self.get_parameter('policy_file').value == result.source:
            self._reverting = self._file_in_use        # policy_file names the policy in use
            try:
                self.set_parameters([Parameter('policy_file', value=self._file_in_use)])
            finally:
                self._reverting = None

    async def _prepare_json(self, text: str, source: str) -> LoadResult:
        """Validate and pack a policy document in a worker thread."""
        done = Future()
        self._loader.start(source, lambda: self._as_run(policy_from_json(
            text, problem=self.problem, source=source), source), done.set_result)
        return await done

    async def _on_load_policy(self, request: Trigger.Request, response: Trigger.Response
                              ) -> Trigger.Response:
        text, error = await fetch_text(self, self._client, self.load_timeout, self._load_group)
        if error is None:
            result = await self._prepare_json(text, f'service {self._client.srv_name}')
            if result.prepared is not None:
                response.success, response.message = True, self._install(result.prepared)
                self._file_in_use = ''
                return response
            error = result.error
            self.get_logger().error(f'policy refused, keeping the current one: {error}')
        else:
            self.get_logger().error(f'load_policy: {error}; keeping the current policy')
        response.success, response.message = False, error
        return response

    # parameters -----------------------------------------------------------------------------

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            reason = check_setting(param.name, param.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            path = param.value
            if param.name == 'policy_file' and path and path != self._reverting:
                try:
                    if policy_file_size(path) <= SYNC_BYTES:   # else: in the background
                        self._staged[path] = PreparedPolicy.of(self._read(path), path,
                                                               self.make_selector)
                except SapgaError as exc:
                    self.get_logger().error(f'policy refused, keeping the current one: {exc}')
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for param in params:
            path = param.value
            if param.name in ('load_timeout', 'markers'):
                setattr(self, param.name, param.value)
            elif param.name != 'policy_file' or not path or path == self._reverting:
                continue
            elif path in self._staged:
                self._loader.supersede()
                self._install(self._staged.pop(path))
                self._file_in_use = path
            else:
                self._load_file(path)
        self._staged.clear()

    def destroy_node(self) -> None:
        """Drop the results of loads still running, then destroy the node."""
        if hasattr(self, '_loader'):
            self._loader.destroy(self)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """``ros2 run sapga_ros policy_node``."""
    return run_node(lambda: PolicyNode(), args, executor=node_executor,
                    parameters=lambda: PARAMETERS, name='policy_node')


if __name__ == '__main__':
    raise SystemExit(main())
