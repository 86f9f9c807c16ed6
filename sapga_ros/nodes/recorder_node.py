"""Recorder node: subscribes to a problem's topics and writes one rosbag2 bag.

A thin shell around ``sapga_ros.recording``: every subscription is raw (the CDR bytes as they
arrived) with the publishers' QoS, durability included (``recorder_qos.py``), and each message
goes unchanged to the bag with its receive time (``log_time``) and publish time
(``header.stamp`` if the type has one, else the publisher's source timestamp).  The bag is a
directory ``<output_dir>/<bag>/`` of ``metadata.yaml`` and MCAP storage files, as rosbag2's
MCAP storage plugin writes them, so ``ros2 bag info/play``, Foxglove, rosbags and
``sapga inspect`` read it.

Node ``recorder_node``; service ``recorder_node/ready`` (``std_srvs/Trigger``): success once
every recorded topic has a publisher (the hand-use ``command`` topic may have none) and each
of its publishers is matched; ``message`` names what is missing.  A simulator with
``wait_for_recorder`` (and ``sapga launch``) starts the run only then, so nothing is lost.

A managed (lifecycle) node: with ``managed`` false (the default) it configures and activates
itself at start, as a plain node; with ``managed`` true it starts unconfigured and waits for
``ros2 lifecycle set /recorder_node configure`` (or a lifecycle manager): *configure* checks
the parameters and makes the bag directory (a failure is one error line and leaves the node
unconfigured), *activate* subscribes and records, *deactivate* unsubscribes and writes what
is buffered (the bag stays open: activate again to go on), *cleanup* and *shutdown* finish
the bag.  The other parameters can then be set while it is unconfigured; each configure
reads them.

Parameters (read-only unless ``managed``; ``recorder_params.py`` declares them,
``recorder_node --help`` prints them with their ranges; msg_configs/params/recorder_node.yaml
lists them):

==============  ==========  =================================================================
name            default     meaning
==============  ==========  =================================================================
problem         acrobot     msg_configs/<problem>.yaml: topic names, QoS, state layout
managed         false       wait for lifecycle transitions instead of recording at once
output_dir      recordings  directory the bag directory is made in (created if missing)
bag             ''          the bag directory's name; '' = ``<problem>_<UTC time>``.  An
                            existing directory is never overwritten
topics          (problem)   topics to record; default: the problem's state, command,
                            command_stamped, reward, episode_event, exemplar_index and
                            markers topics.  An entry is a name
                            (type from the problem, else found on the graph once a publisher
                            appears) or ``name:pkg/msg/Type`` (quote it inside ``-p`` lists:
                            ``-p 'topics:=["odom:nav_msgs/msg/Odometry"]'``)
split           run         ``run``: one storage file; ``episode``: a new storage file of
                            the same bag at each episode ``start`` event (as rosbag2 splits)
chunk_size      65536       [bytes] uncompressed MCAP chunk (at most 16 MiB, the largest
                            chunk every reader of the bag accepts)
flush_period    1.0         [s] close the chunk in progress at least this often (0: by size);
                            the most a SIGKILL of the recorder can lose
compression     zstd        ``zstd``, ``lz4`` or ``none`` (MCAP chunk compression)
queue_depth     1000        subscription history depth (keep_last) per publisher of a role
delta           (problem)   goal delta the run uses, written to the bag metadata; default:
                            the problem's ``episode.delta``
==============  ==========  =================================================================

Ctrl-C, SIGTERM and a shutdown of the ROS context write every message the subscriptions
still hold (a recorder that fell behind loses none of them: ``_drain``) and finish the bag
(summary, footer, ``metadata.yaml``); after a SIGKILL, ``sapga bag reindex DIR`` completes
it.  A write that fails (a full disk) is logged as an error at once; the recorder keeps
trying (a new storage file once the disk takes data again), and at the end
``metadata.yaml`` counts what the files hold, marks the bag ``incomplete`` in its
``custom_data``, and the recorder exits with status 1.  Messages that never reached the
recorder (its queue overflowed: ``queue_depth``, or the network lost them)
are counted per topic from the publishers' sequence numbers, with a throttled warning and a
total in the final line (``sim_nodes/ros/dropped.py``).  (Over 300 lines: the node's
subscriptions, readiness service, lifecycle transitions and the write-failure path that must
stay next to them; the bag itself is ``sapga_ros.recording``.)
"""
from __future__ import annotations

import functools
import importlib
import json
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import Trigger

from sapga_ros.errors import SapgaError
from sapga_ros.nodes.recorder_params import PARAMETERS
from sapga_ros.nodes.recorder_qos import (adapt_to_offers, describe, incompatible,
                                          offered_profile, role_qos)
from sapga_ros.recording.events import OPTIONAL_ROLES, ROLE_TYPES
from sapga_ros.recording.metadata import TopicInfo
from sapga_ros.recording.schemas import (full_type_name, message_definition, publish_time_ns,
                                         type_hash)
from sapga_ros.recording.session import RecordingSession, free_bag_path, utc_stamp
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import THROTTLE_S, run_node, topic_names
from sim_nodes.ros.diagnostics import ERROR, OK, WARN, NodeDiagnostics, Report
from sim_nodes.ros.dropped import DropCounter
from sim_nodes.ros.runner import EXIT_FAILED
from sim_nodes.ros.params import check, declare

NODE_NAME = 'recorder_node'  # its readiness service: recorder_node/ready
GRAPH_PERIOD_S = 1.0        # [s] between looks at the graph (new publishers, their QoS)


def message_class(type_name: str) -> Any:
    """The Python class of a ROS message type 'pkg/msg/Type'."""
    pkg, ns, name = full_type_name(type_name).split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.{ns}'), name)
    except (ImportError, AttributeError) as exc:
        raise SapgaError(f'message type {type_name!r} is not installed') from exc


class RecorderNode(LifecycleNode):
    """Raw subscriptions -> ``RecordingSession`` (one bag, split per run or per episode)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare(self, PARAMETERS[:2])
        self._problem = load_problem(p['problem'])
        self.managed = bool(p['managed'])
        rest = PARAMETERS[2:] if not self.managed else tuple(
            replace(q, read_only=False) for q in PARAMETERS[2:])    # set while unconfigured
        p.update(declare(self, rest, self._problem))
        self._roles = {role: self._resolve(name)
                       for role, name in topic_names(self._problem).items() if role in ROLE_TYPES}
        self._session: RecordingSession | None = None
        self._finished: tuple[Any, int] = (None, 0)    # the last bag finished: path, count
        self._subs: dict[str, tuple[Any, str, QoSProfile]] = {}
        self.dropped: dict[str, DropCounter] = {}
        self._pending: dict[str, str | None] = {}
        self._active_timers: list[Any] = []
        self.active = False
        self.write_errors = 0
        self.failed = False         # a write failed: the bag is incomplete, exit status 1
        self._ready_srv = self.create_service(Trigger, '~/ready', self._on_ready)
        self.diagnostics = NodeDiagnostics(self, 'recorder', self._problem.name, self._report)
        if not self.managed:
            self._configure(p)          # a bad parameter: one line and exit 2, as any node
            self.trigger_configure()
            self.trigger_activate()
        else:
            self.get_logger().info('managed: unconfigured, waiting for the configure '
                                   'transition')

    def _configure(self, p: dict[str, Any]) -> None:
        """Make the bag (SapgaError if a parameter or the output directory is refused)."""
        self._depth = p['queue_depth']
        self._split = p['split']
        self._flush_period = p['flush_period']
        wanted = self._wanted_topics()
        name = p['bag'] or f'{self._problem.name}_{utc_stamp()}'
        path = free_bag_path(p['output_dir'], name) if not p['bag'] else \
            self._plain_name(p['output_dir'], p['bag'])
        self._session = RecordingSession(
            path, split=p['split'], event_topic=self._roles['event'],
            chunk_size=p['chunk_size'], compression=p['compression'],
            metadata={'problem': self._problem.name, 'delta': repr(p['delta']),
                      'topics': json.dumps(self._roles, sort_keys=True, allow_nan=False),
                      'state_names': json.dumps(self._problem.state_names, allow_nan=False),
                      'node': self.get_fully_qualified_name()})
        # the event topic first: of messages ready together, the executor takes it first, so
        # an episode's first messages land in its own file (split 'episode')
        self._pending = dict(sorted(wanted.items(),
                                    key=lambda kv: kv[0] != self._roles['event']))

    # lifecycle --------------------------------------------------------------------------

    def _settings(self) -> dict[str, Any]:
        """The parameters as set now, each checked (SapgaError naming the first refused)."""
        values = {q.name: self.get_parameter(q.name).value for q in PARAMETERS[2:]}
        for name, value in values.items():
            reason = check(PARAMETERS, name, value) if value is not None else None
            if reason:
                raise SapgaError(reason)
        return values

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._session is None:
            try:
                self._configure(self._settings())
            except SapgaError as exc:
                self.get_logger().error(f'configure failed, still unconfigured: '
                                        f'{" ".join(str(exc).split())}'[:500])
                return TransitionCallbackReturn.FAILURE
            self.get_logger().info(f'configured: bag {self._session.path}')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        self._check_graph()
        self._active_timers = [self.create_timer(GRAPH_PERIOD_S, self._check_graph)]
        if self._flush_period > 0:
            self._active_timers.append(self.create_timer(self._flush_period, self._flush))
        self.get_logger().info(f'recording {", ".join([*self._subs, *self._pending])} to '
                               f'{self._session.path} (split per {self._split})')
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop()
        self.get_logger().info(f'paused: {self.message_count} messages in {self.bag_path}')
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._finish()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._finish()
        return TransitionCallbackReturn.SUCCESS

    def _stop(self) -> None:
        """Write what the subscriptions still hold, unsubscribe (the topics wait in
        ``_pending`` for the next activate); flush."""
        self._drain()
        self.active = False
        for timer in self._active_timers:
            self.destroy_timer(timer)
        self._active_timers = []
        for topic, (sub, type_name, _) in list(self._subs.items()):
            self.destroy_subscription(sub)
            self._pending[topic] = type_name
        self._subs.clear()
        if self._session is not None:
            self._flush()

    def _finish(self) -> None:
        """Stop, then finish the bag (summary, footer, metadata.yaml) and say what it holds;
        the bag is finished even if stopping fails."""
        try:
            if self.active:
                self._stop()
        finally:
            self._close()

    def _close(self) -> None:
        s, self._session = self._session, None
        if s is None:
            return
        self._finished = (s.path, s.message_count)
        line = (f'wrote {s.path}: {s.message_count} messages in '
                f'{len(s.bag.metadata.files)} storage file(s)')
        try:
            s.close()
        except SapgaError as exc:
            self.failed = True
            line = f'error: {exc}'
        if self.write_errors:
            line += f'; {self.write_errors} writes failed'
        lost = sum(d.count for d in self.dropped.values())
        if lost:
            line += f'; {lost} messages were dropped before they reached the recorder'
        if self.context.ok():
            log = self.get_logger()
            (log.error if self.failed else log.info)(line)
        else:   # after a signal the context is down and rosout is gone
            print(f'[recorder] {line}', file=sys.stderr, flush=True)

    # names ------------------------------------------------------------------------------

    @staticmethod
    def _plain_name(output_dir: str, bag: str) -> Path:
        if '/' in bag or bag in ('.', '..') or len(bag) > 200:
            raise SapgaError(f'recorder: bag {bag[:80]!r}: expected a plain directory name')
        return Path(output_dir) / bag

    def _resolve(self, name: str) -> str:
        try:
            return self.resolve_topic_name(name)
        except Exception as exc:  # noqa: BLE001 - rclpy raises several kinds for bad names
            raise SapgaError(f'recorder: topic name {name!r} is not valid ({exc})') from exc

    def _wanted_topics(self) -> dict[str, str | None]:
        """Resolved topic -> message type (None: find it on the graph) of ``topics``."""
        role_types = {topic: ROLE_TYPES[role] for role, topic in self._roles.items()}
        requested = self.get_parameter_or(
            'topics', Parameter('topics', Parameter.Type.STRING_ARRAY, [])).value
        wanted: dict[str, str | None] = {}
        for entry in requested or self._roles.values():
            name, _, type_name = str(entry).partition(':')
            topic = self._resolve(name.strip())
            wanted[topic] = (full_type_name(type_name.strip()) if type_name.strip()
                             else role_types.get(topic))
        return wanted

    # subscriptions ----------------------------------------------------------------------

    def _base_qos(self, topic: str) -> QoSProfile:
        role = next((r for r, t in self._roles.items() if t == topic), None)
        if role is None:
            return QoSProfile(depth=self._depth)
        return role_qos(self._problem, role, self._depth)

    def _offers(self, topic: str) -> list[QoSProfile]:
        try:
            return [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        except RuntimeError:    # the context is shut down (draining after a signal)
            return []

    def _subscribe(self, topic: str, type_name: str, qos: QoSProfile) -> bool:
        try:
            message_definition(type_name)       # the schema must be writable
            msg_type = message_class(type_name)
        except SapgaError as exc:
            self.get_logger().error(f'not recording {topic}: {exc}')
            return False
        sub = self.create_subscription(msg_type, topic,
                                       functools.partial(self._on_message, topic, type_name),
                                       qos, raw=True)
        self._subs[topic] = (sub, type_name, qos)
        if topic not in self.dropped:
            self.dropped[topic] = DropCounter(self.get_logger(), topic,
                                              lambda: self._subs[topic][0].get_publisher_count(),
                                              qos.depth)
        return True

    def _check_graph(self) -> None:
        """Subscribe to pending topics (type known or now published); subscribe again to a
        topic whose publishers use another type (nothing recorded yet) or offer less than
        the subscription asks (its QoS could not match them)."""
        for topic, type_name in list(self._pending.items()):
            publishers = self.get_publishers_info_by_topic(topic)
            type_name = type_name or next((p.topic_type for p in publishers), None)
            if type_name:
                del self._pending[topic]
                self._subscribe(topic, type_name, adapt_to_offers(
                    self._base_qos(topic), [p.qos_profile for p in publishers]))
        for topic, (sub, type_name, qos) in list(self._subs.items()):
            publishers = self.get_publishers_info_by_topic(topic)
            offers = [p.qos_profile for p in publishers]
            types = sorted({p.topic_type for p in publishers})
            if types and type_name not in types and not self._recorded(topic):
                self.get_logger().warning(f'{topic}: published as {types[0]}, not {type_name}: '
                                          f'recording {types[0]}')
                self.destroy_subscription(sub)      # DDS: one type per topic and process
                del self._subs[topic]
                if not self._subscribe(topic, types[0], adapt_to_offers(qos, offers)):
                    self._pending[topic] = None
            elif incompatible(qos, offers):
                new = adapt_to_offers(qos, offers)
                self.get_logger().warning(f'{topic}: a publisher offers less than '
                                          f'{describe(qos)}: subscribing {describe(new)}')
                if self._subscribe(topic, type_name, new):
                    self.destroy_subscription(sub)

    def _recorded(self, topic: str) -> bool:
        """Whether the bag has the topic (its type and QoS are then fixed)."""
        return self._session is not None and topic in self._session.bag.metadata.topics

    def missing(self) -> list[str]:
        """What the recorder lacks to hear every publisher of every recorded topic."""
        if not self.active:
            return ['the activate transition (managed: the node is '
                    f'{"configured" if self._session else "unconfigured"})']
        lacks = [f'{t} (type unknown: no publisher yet)' for t in self._pending]
        optional = {self._roles.get(role) for role in OPTIONAL_ROLES}
        for topic, (sub, _, _) in self._subs.items():
            matched, on_graph = sub.get_publisher_count(), self.count_publishers(topic)
            need = on_graph if topic in optional else max(1, on_graph)
            if matched < need:
                lacks.append(f'{topic} ({matched} of {need} publishers matched)')
        return lacks

    def _on_ready(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        lacks = self.missing()
        response.success = not lacks
        response.message = (f'recording {len(self._subs)} topics to {self.bag_path}'
                            if not lacks else 'waiting for ' + '; '.join(lacks))
        return response

    def _report(self) -> Report:
        """The node's /diagnostics: the bag, what it holds, what it lacks."""
        lacks = self.missing()
        dropped = sum(d.count for d in self.dropped.values())
        if self.write_errors:
            level, message = ERROR, f'{self.write_errors} messages could not be written'
        elif lacks:
            level, message = WARN, 'waiting for ' + '; '.join(lacks)
        else:
            level, message = OK, f'recording {len(self._subs)} topics'
        return level, message[:300], {
            'bag': str(self.bag_path or ''), 'messages': self.message_count,
            'topics': len(self._subs), 'dropped': dropped, 'write_errors': self.write_errors,
            'ready': not lacks}

    # messages ---------------------------------------------------------------------------

    @property
    def message_count(self) -> int:
        """Messages recorded so far (in the bag being written, else the last one finished)."""
        return self._session.message_count if self._session is not None else self._finished[1]

    @property
    def bag_path(self) -> Any:
        """The bag being written, else the last one finished (None before any)."""
        return self._session.path if self._session is not None else self._finished[0]

    def _on_message(self, topic: str, type_name: str, data: bytes,
                    msg_info: dict[str, Any]) -> None:
        if self._session is None or not self.active:
            return
        self.dropped[topic].seen(msg_info)
        receive_ns = int(msg_info.get('received_timestamp') or 0) or time.time_ns()
        source_ns = int(msg_info.get('source_timestamp') or 0)
        if not self._recorded(topic):
            offers = [offered_profile(q) for q in self._offers(topic)] or [
                offered_profile(self._subs[topic][2])]
            self._session.add_topic(TopicInfo(topic, type_name, offers, type_hash(type_name)))
        try:
            self._session.write(topic, data, receive_ns,
                                publish_time_ns(type_name, data, source_ns, receive_ns))
        except SapgaError as exc:
            self._write_failed(f'message on {topic} not recorded', exc)

    def _drain(self) -> None:
        """Take every message the subscriptions hold that the executor has not handed over
        yet and write it: a recorder that fell behind (descheduled, a burst) and is then
        stopped loses nothing that reached it.  The executor takes one message per topic
        per turn, so a busy topic (``markers``: two publishers) is the furthest behind.
        They are written in the order they were received, as the executor would have."""
        if self._session is None or not self.active:
            return
        held = []
        for topic, (sub, type_name, qos) in list(self._subs.items()):
            for _ in range(qos.depth):      # what the history holds (publishers may go on)
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                except (InvalidHandle, RuntimeError):   # destroyed, or the context is gone
                    break
                if taken is None:
                    break
                held.append((int(taken[1].get('received_timestamp') or 0), len(held), topic,
                             type_name, taken))
        for _, _, topic, type_name, (data, info) in sorted(held):
            self._on_message(topic, type_name, data, info)

    def _flush(self) -> None:
        try:
            self._session.flush()
        except SapgaError as exc:
            self._write_failed('the chunk in progress could not be written', exc)

    def _write_failed(self, what: str, exc: SapgaError) -> None:
        """Say at once, loudly, that recording fails; then at most every THROTTLE_S."""
        self.write_errors += 1
        if not self.failed:
            self.failed = True
            self.get_logger().error(f'CANNOT WRITE THE BAG: {exc}; messages are being lost '
                                    'until it can write again; the bag will be marked '
                                    'incomplete')
            return
        self.get_logger().error(f'{what} ({self.write_errors} failures so far): {exc}',
                                throttle_duration_sec=THROTTLE_S)

    def destroy_node(self) -> None:
        """Finish the bag (summary, footer, metadata.yaml), then destroy the node."""
        try:
            if getattr(self, '_session', None) is not None:
                self._finish()
        finally:
            super().destroy_node()


def _no_interrupt(signum: int, frame: Any) -> None:
    """SIGINT: nothing here; rclpy's handler has already stopped spinning."""


def _finishing() -> None:
    """SIGTERM from now on: ignored, so that a second one lets the bag finish."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def main(args: list[str] | None = None) -> int:
    """Run the recorder until Ctrl-C, SIGTERM or shutdown; the bag is finished."""
    # rclpy's SIGINT and SIGTERM handlers shut the context down: spinning then ends between
    # callbacks and `finally` finishes the bag.  They chain to the Python handler, which must
    # not raise KeyboardInterrupt in the middle of a write.
    signal.signal(signal.SIGINT, _no_interrupt)
    made: list[RecorderNode] = []

    def make() -> RecorderNode:
        made.append(RecorderNode())
        return made[-1]

    code = run_node(make, args, executor=lambda node: SingleThreadedExecutor(),
                    parameters=lambda: PARAMETERS, name='recorder_node', on_exit=_finishing,
                    signal_handler_options=SignalHandlerOptions.ALL)
    return EXIT_FAILED if code == 0 and made and made[0].failed else code


if __name__ == '__main__':
    raise SystemExit(main())
