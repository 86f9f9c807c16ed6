"""The launch's own ROS node: hears episode events, states and the trainer's diagnostics,
calls the nodes' services (``LaunchRos``: its context, node and executor thread).

The node joins the launch's namespace and remaps (``ros_args.RosOptions``), so its relative
topic and service names are those of the nodes it launched.
"""
from __future__ import annotations

import threading
import time
from typing import Any

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

from sapga_ros.launch.supervisor import LaunchError, Supervisor
from sapga_ros.launch.ros_args import RosOptions
from sapga_ros.recording.events import parse_event
from sim_nodes.problem import Problem
from sim_nodes.ros.common import EVENT_QOS, qos_profile, spin_guarded, stamp_ns, topic_names

CALL_TIMEOUT_S = 30.0      # [s] for a service call to a node
# [s] before an idempotent request is sent again: a server that has not yet discovered a new
# client's response reader drops the response ("failed to send response (timeout)", a known
# race of ROS 2 services under load); asking again is then the only way to get one
RESEND_S = 5.0
END_EVENTS = ('goal', 'step_limit', 'end_stop')


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

    def __init__(self, problem: Problem, options: RosOptions | None = None) -> None:
        self.options = options or RosOptions()
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context,   # not sys.argv: the launch's own
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = LaunchNode(problem, context=self.context,
                               cli_args=self.options.launch_node_args())
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
             timeout: float = CALL_TIMEOUT_S, idempotent: bool = False) -> Any:
        """Call service ``name`` and wait for the response, watching the children; an
        ``idempotent`` request is sent again every RESEND_S seconds without an answer (the
        first answer to any of them is the response)."""
        client = self.node.create_client(srv_type, name)
        try:
            sup.wait(client.service_is_ready, timeout=timeout, what=f'service {name}')
            futures = [client.call_async(request)]
            resend = [time.monotonic() + RESEND_S]

            def answered() -> Any:
                done = next((f for f in futures if f.done()), None)
                if done is None and idempotent and time.monotonic() >= resend[0]:
                    futures.append(client.call_async(request))
                    resend[0] = time.monotonic() + RESEND_S
                return done

            return sup.wait(answered, timeout=timeout,
                            what=f'the response of {name}').result()
        finally:
            self.node.destroy_client(client)

    def trigger(self, sup: Supervisor, name: str, idempotent: bool = False) -> Trigger.Response:
        """Call a std_srvs/Trigger service (``idempotent``: see ``call``)."""
        return self.call(sup, Trigger, name, Trigger.Request(), idempotent=idempotent)

    def set_parameters(self, sup: Supervisor, node: str, values: dict[str, Any]) -> None:
        """Set parameters of ``node``; ``LaunchError`` with the node's reason if refused."""
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=v).to_parameter_msg()
                              for k, v in values.items()]
        response = self.call(sup, SetParameters, f'{node}/set_parameters', request,
                             idempotent=True)
        for (key, _), result in zip(values.items(), response.results):
            if not result.successful:
                raise LaunchError(f'{node} refused {key}: {result.reason}')

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self._thread.join(timeout=2.0)
