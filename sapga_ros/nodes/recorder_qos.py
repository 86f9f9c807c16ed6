"""QoS of the recorder's subscriptions: the publishers' own, durability included.

- A topic of the problem's contract is subscribed with the QoS its publisher uses
  (``sim_nodes.ros.common``: ``qos_profile(problem)`` for state, command, reward and exemplar,
  ``EVENT_QOS``, transient local, for episode events), with a deeper history: at least the
  recorder's ``queue_depth`` per publisher of the role (``markers`` has two, one history);
- a topic whose publishers are on the graph is subscribed as rosbag2 does
  (``Rosbag2QoS::adapt_request_to_offers``): reliable if every publisher is reliable, transient
  local if every publisher is, so the subscription matches all of them;
- ``incompatible`` tells when a publisher appears that the subscription cannot match (a
  best-effort or volatile one): the recorder then subscribes again, adapted.
"""
from __future__ import annotations

from typing import Any, Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sapga_ros.recording.events import ROLE_PUBLISHERS
from sapga_ros.recording.metadata import qos_profile as bag_qos
from sim_nodes.problem import Problem
from sim_nodes.ros.common import EVENT_QOS, qos_profile


def role_qos(problem: Problem, role: str, depth: int) -> QoSProfile:
    """The publisher's QoS of a contract role, history ``depth`` (at least the publisher's)
    for each publisher of the role: the publishers of one topic share one history, and a
    recorder that falls behind by N steps holds N messages of each."""
    base = EVENT_QOS if role == 'event' else qos_profile(problem)
    writers = ROLE_PUBLISHERS.get(role, 1)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(depth, base.depth) * writers,
                      reliability=base.reliability, durability=base.durability)


def adapt_to_offers(base: QoSProfile, offers: Sequence[QoSProfile]) -> QoSProfile:
    """``base`` made compatible with every offered profile (rosbag2's rule); base if none."""
    if not offers:
        return base
    reliable = all(o.reliability == ReliabilityPolicy.RELIABLE for o in offers)
    durable = all(o.durability == DurabilityPolicy.TRANSIENT_LOCAL for o in offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=base.depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE)


def incompatible(sub: QoSProfile, offers: Sequence[QoSProfile]) -> bool:
    """Whether some offer cannot match ``sub`` (reliability or durability requested higher)."""
    return any((sub.reliability == ReliabilityPolicy.RELIABLE
                and o.reliability == ReliabilityPolicy.BEST_EFFORT)
               or (sub.durability == DurabilityPolicy.TRANSIENT_LOCAL
                   and o.durability == DurabilityPolicy.VOLATILE) for o in offers)


def offered_profile(qos: QoSProfile) -> dict[str, Any]:
    """An rclpy profile in rosbag2's ``offered_qos_profiles`` form."""
    return bag_qos(
        history=qos.history.name.lower(), depth=qos.depth,
        reliability=qos.reliability.name.lower(), durability=qos.durability.name.lower(),
        deadline=qos.deadline.nanoseconds, lifespan=qos.lifespan.nanoseconds,
        liveliness=qos.liveliness.name.lower(),
        liveliness_lease_duration=qos.liveliness_lease_duration.nanoseconds,
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def describe(qos: QoSProfile) -> str:
    """'reliable transient_local depth 1000'."""
    return (f'{qos.reliability.name.lower()} {qos.durability.name.lower()} '
            f'depth {qos.depth}')
