"""Recorder node (SPEC 4): subscribes to a problem's topics and writes them to MCAP.

A thin shell around ``sapga_ros.recording.mcap_io``:
every subscription is raw (the CDR bytes as they
arrived), and each message goes unchanged to the core writer with its receive time
(``log_time``) and publish time (``header.stamp`` if the type has one, else the publisher's
source timestamp).  Files are MCAP profile ``ros2`` with full ``ros2msg`` definitions, so
Foxglove, ``ros2 bag info`` and ``sapga inspect`` read them.

Parameters (all read-only; msg_configs/params/recorder_node.yaml lists them):

==============  ==========  =================================================================
name            default     meaning
==============  ==========  =================================================================
problem         acrobot     msg_configs/<problem>.yaml: topic names, QoS, state layout
output_dir      recordings  directory of the .mcap files (created if missing)
topics          (problem)   topics to record; default: the problem's state, command, reward,
                            episode_event and exemplar_index topics.  An entry is a name
                            (type from the problem, else found on the graph once a publisher
                            appears) or ``name:pkg/msg/Type`` (quote it inside ``-p`` lists:
                            ``-p 'topics:=["odom:nav_msgs/msg/Odometry"]'``)
split           run         ``run`` (default): one file per recorder run, episode events
                            inside: one timeline, nothing falls between files; ``episode``:
                            a new file at each episode ``start`` event
chunk_size      65536       [bytes] uncompressed MCAP chunk: the most a SIGKILL can lose
flush_period    1.0         [s] close the chunk in progress at least this often (0: by size)
compression     zstd        ``zstd``, ``lz4`` or ``none``
queue_depth     1000        subscription history depth (keep_last)
delta           0.0         goal delta written to the file metadata (0: the problem default)
==============  ==========  =================================================================

Files are named ``<problem>_<UTC time>.mcap`` (``..._ep<NNNN>.mcap`` per episode), opened at
the first message, never overwritten.  Ctrl-C, SIGTERM and a shutdown of the ROS context
finish the file (summary and footer); after a SIGKILL the file is readable up to its last
complete chunk, and every episode end event closes the chunk in progress.
"""
from __future__ import annotations

import functools
import importlib
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from sapga_ros.errors import SapgaError
from sapga_ros.recording.mcap_io import (COMPRESSIONS, DEFAULT_CHUNK_SIZE, DEFAULT_ROLE_TOPICS,
                                         ROLE_TYPES, SPLITS, ChannelInfo, RecordingSession,
                                         full_type_name, message_definition, publish_time_ns,
                                         qos_profiles_yaml, utc_stamp)
from sim_nodes.problem import load_problem

_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE,
               'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}


def _ro(description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=True)


def message_class(type_name: str) -> Any:
    """The Python class of a ROS message type 'pkg/msg/Type'."""
    pkg, ns, name = full_type_name(type_name).split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.{ns}'), name)
    except (ImportError, AttributeError) as exc:
        raise SapgaError(f'message type {type_name!r} is not installed') from exc


def profile_dict(qos: QoSProfile) -> dict[str, Any]:
    """An rclpy QoS profile as qos_profiles_yaml takes it."""
    return {
        'history': qos.history.name.lower(), 'depth': qos.depth,
        'reliability': qos.reliability.name.lower(),
        'durability': qos.durability.name.lower(),
        'deadline': qos.deadline.nanoseconds, 'lifespan': qos.lifespan.nanoseconds,
        'liveliness': qos.liveliness.name.lower(),
        'liveliness_lease_duration': qos.liveliness_lease_duration.nanoseconds,
        'avoid_ros_namespace_conventions': qos.avoid_ros_namespace_conventions,
    }


class RecorderNode(Node):
    """Raw subscriptions → ``RecordingSession`` (one MCAP file per run or per episode)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('recorder', **kwargs)
        problem_name = self.declare_parameter(
            'problem', 'acrobot', _ro('msg_configs/<problem>.yaml to record')).value
        output_dir = self.declare_parameter(
            'output_dir', 'recordings', _ro('directory of the MCAP files')).value
        self.declare_parameter('topics', Parameter.Type.STRING_ARRAY,
                               _ro('topics: name or name:pkg/msg/Type (default: the problem)'))
        split = self.declare_parameter('split', 'run', _ro(' or '.join(SPLITS))).value
        chunk_size = self.declare_parameter(
            'chunk_size', DEFAULT_CHUNK_SIZE, _ro('uncompressed chunk size [bytes]')).value
        flush_period = self.declare_parameter(
            'flush_period', 1.0, _ro('close the open chunk this often [s]; 0: never')).value
        compression = self.declare_parameter(
            'compression', 'zstd', _ro(' or '.join(COMPRESSIONS))).value
        depth = self.declare_parameter(
            'queue_depth', 1000, _ro('subscription history depth')).value
        delta = self.declare_parameter(
            'delta', 0.0, _ro('goal delta for the metadata; 0: the problem default')).value
        if depth < 1:
            raise SapgaError(f'recorder: queue_depth {depth}: expected >= 1')
        if flush_period < 0:
            raise SapgaError(f'recorder: flush_period {flush_period}: expected >= 0 s')

        self._problem = load_problem(problem_name)
        ros = self._problem.ros
        given = ros.get('topics') if isinstance(ros.get('topics'), dict) else {}
        role_topics = {role: self._resolve(str(given.get(role) or DEFAULT_ROLE_TOPICS[role]))
                       for role in ROLE_TYPES}
        wanted = self._wanted_topics(role_topics)
        self._qos = self._subscription_qos(ros.get('qos') or {}, depth)
        event_topic = role_topics['event']
        self._session = RecordingSession(
            output_dir, f'{self._problem.name}_{utc_stamp()}', split=split,
            event_topic=event_topic, chunk_size=chunk_size, compression=compression,
            metadata={'problem': self._problem.name,
                      'delta': repr(float(delta) if delta > 0 else self._problem.default_delta),
                      'topics': json.dumps(role_topics, sort_keys=True),
                      'state_names': json.dumps(self._problem.state_names),
                      'node': self.get_fully_qualified_name()})
        self._channels: dict[str, ChannelInfo] = {}
        self._pending: dict[str, None] = {}
        # the event topic first: of messages ready together, the executor takes it first, so
        # an episode's first messages land in its own file (split 'episode')
        for topic, type_name in sorted(wanted.items(), key=lambda kv: kv[0] != event_topic):
            if type_name:
                self._subscribe(topic, type_name)
            else:
                self._pending[topic] = None
        if self._pending:
            self._discovery = self.create_timer(1.0, self._discover)
        if flush_period > 0:
            self._flusher = self.create_timer(flush_period, self._session.flush)
        self.get_logger().info(f'recording {", ".join(wanted)} to '
                               f'{Path(output_dir).resolve()} (split per {split})')

    def _resolve(self, name: str) -> str:
        try:
            return self.resolve_topic_name(name)
        except Exception as exc:  # noqa: BLE001 - rclpy raises several kinds for bad names
            raise SapgaError(f'recorder: topic name {name!r} is not valid ({exc})') from exc

    def _wanted_topics(self, role_topics: dict[str, str]) -> dict[str, str | None]:
        """Resolved topic -> message type (None: find it on the graph) of ``topics``."""
        role_types = {topic: ROLE_TYPES[role] for role, topic in role_topics.items()}
        requested = self.get_parameter_or(
            'topics', Parameter('topics', Parameter.Type.STRING_ARRAY, [])).value
        wanted: dict[str, str | None] = {}
        for entry in requested or role_topics.values():
            name, _, type_name = str(entry).partition(':')
            topic = self._resolve(name.strip())
            wanted[topic] = (full_type_name(type_name.strip()) if type_name.strip()
                             else role_types.get(topic))
        return wanted

    def _subscription_qos(self, qos: dict, depth: int) -> QoSProfile:
        reliability = str(qos.get('reliability', 'reliable'))
        durability = str(qos.get('durability', 'volatile'))
        if reliability not in _RELIABILITY or durability not in _DURABILITY:
            raise SapgaError(f'{self._problem.source}: ros.qos: reliability {reliability!r} / '
                             f'durability {durability!r} not understood')
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                          reliability=_RELIABILITY[reliability],
                          durability=_DURABILITY[durability])

    @property
    def message_count(self) -> int:
        """Messages recorded so far (all files)."""
        return self._session.message_count

    def _subscribe(self, topic: str, type_name: str) -> None:
        try:
            message_definition(type_name)       # the schema must be writable
            msg_type = message_class(type_name)
        except SapgaError as exc:
            self.get_logger().error(f'not recording {topic}: {exc}')
            return
        self.create_subscription(msg_type, topic,
                                 functools.partial(self._on_message, topic, type_name),
                                 self._qos, raw=True)

    def _discover(self) -> None:
        """Subscribe to pending topics whose type has appeared on the graph."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._pending and types:
                del self._pending[topic]
                self._subscribe(topic, types[0])
                self.get_logger().info(f'found {topic} ({types[0]})')
        if not self._pending:
            self._discovery.cancel()

    def _channel(self, topic: str, type_name: str) -> ChannelInfo:
        """Channel info of a topic, built at its first message from the publishers' offers."""
        info = self._channels.get(topic)
        if info is None:
            offers = [profile_dict(p.qos_profile)
                      for p in self.get_publishers_info_by_topic(topic)]
            if not offers:
                offers = [profile_dict(self._qos) | {'depth': self._problem.ros.get(
                    'qos', {}).get('depth', 10)}]
            info = ChannelInfo(topic, type_name, qos_profiles_yaml(offers))
            self._channels[topic] = info
        return info

    def _on_message(self, topic: str, type_name: str, data: bytes,
                    msg_info: dict[str, Any]) -> None:
        receive_ns = int(msg_info.get('received_timestamp') or 0) or time.time_ns()
        source_ns = int(msg_info.get('source_timestamp') or 0)
        self._session.write(self._channel(topic, type_name), data, receive_ns,
                            publish_time_ns(type_name, data, source_ns, receive_ns))

    def destroy_node(self) -> None:
        """Finish the open MCAP file (summary, footer), then destroy the node."""
        try:
            lines = [f'wrote {p}' for p in self._session.paths] or [
                'no message received: no file written']
            try:
                self._session.close()
            except SapgaError as exc:
                lines.append(f'error: {exc}')
            for line in lines:
                if self.context.ok():
                    self.get_logger().info(line)
                else:   # after a signal the context is down and rosout is gone
                    print(f'[recorder] {line}', file=sys.stderr, flush=True)
        finally:
            super().destroy_node()


def _no_interrupt(signum: int, frame: Any) -> None:
    """SIGINT: nothing here; rclpy's handler has already stopped spin()."""


def main(args: list[str] | None = None) -> int:
    """Run the recorder until Ctrl-C, SIGTERM or shutdown; the MCAP file is finished."""
    # rclpy's SIGINT and SIGTERM handlers shut the context down: spin() then raises
    # ExternalShutdownException between callbacks and `finally` finishes the file.  They chain
    # to the Python handler, which must not raise KeyboardInterrupt in the middle of a write.
    signal.signal(signal.SIGINT, _no_interrupt)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.ALL)
    node = None
    try:
        node = RecorderNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SapgaError as exc:
        print(f'recorder_node: error: {exc}', file=sys.stderr, flush=True)
        return 1
    except Exception:  # noqa: BLE001
        if rclpy.ok():
            raise
        # Ctrl-C while starting up: the context was shut down under the constructor
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)   # a second SIGTERM: let the file finish
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
