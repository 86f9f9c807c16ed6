"""Serialized ``MarkerArray``s of a pendulum drawing, made by patching a template's bytes.

rclpy converts a Python message to C field by field: publishing one of the simulator's
marker arrays took about 200 us on a shared machine (its bytes: about 5 us).  The arrays of one
``PendulumMarkers`` differ from step to step only in their stamps, the markers' pose
positions, actions and points, so ``MarkerBytes`` serializes an array once per shape (the
actions and point counts of its markers), with a distinct sentinel in every field that
varies, finds where each sentinel landed in the CDR bytes, and from then on writes the new
values at those offsets into a copy of the template: bytes that decode to the message
``serialize_message`` would give (only CDR padding may differ), for a few microseconds.
``rclpy``'s ``Publisher.publish`` takes them as they are.  An array whose sentinels cannot
be found unambiguously is serialized the ordinary way.

``patched`` is the same without a message: the drawing hands over its shape, one stamp and
every marker's pose and point coordinates (``PendulumMarkers.state_bytes``), so no ``Point``
message is made or read per step (building them was most of the markers' cost).
"""
from __future__ import annotations

import copy
import struct
from typing import Any, Callable, Sequence

from rclpy.serialization import serialize_message

_SEC0 = 0x5A5A0000        # stamp sentinels: seconds, nanoseconds (+ the marker's number)
_NSEC0 = 0x3C3C0000
MAX_SHAPES = 16            # templates kept (a drawing has two or three shapes)
_REAL0 = 1.0e300          # pose and point sentinels: _REAL0 * (1 + k * 2**-40)


def _real(k: int) -> float:
    return _REAL0 * (1.0 + k * 2.0 ** -40)


def _find(data: bytes, value: bytes) -> int | None:
    at = data.find(value)
    return at if at >= 0 and data.find(value, at + 1) < 0 else None


class MarkerBytes:
    """``bytes_of(array)``: the CDR serialization of a MarkerArray (see the module)."""

    def __init__(self) -> None:
        self._templates: dict[tuple, tuple[bytes, list[tuple[int, int, int]]] | None] = {}

    def bytes_of(self, array: Any) -> bytes:
        """The serialized ``array``: decodes as ``serialize_message(array)`` does."""
        markers = array.markers
        shape = tuple((m.action, len(m.points)) for m in markers)
        template = self._template_of(shape, lambda: array)
        if template is None:
            return serialize_message(array)
        data, offsets = template
        buf = bytearray(data)
        for m, (stamp_at, pose_at, points_at) in zip(markers, offsets):
            stamp = m.header.stamp
            struct.pack_into('<iI', buf, stamp_at, stamp.sec, stamp.nanosec)
            p = m.pose.position
            struct.pack_into('<3d', buf, pose_at, p.x, p.y, p.z)
            if points_at >= 0:
                points = m.points
                struct.pack_into(f'<{3 * len(points)}d', buf, points_at,
                                 *[c for q in points for c in (q.x, q.y, q.z)])
        return bytes(buf)

    def patched(self, shape: tuple, make: Callable[[], Any], stamp: int,
                values: Sequence[tuple[Sequence[float], Sequence[float]]]) -> bytes:
        """The serialized array ``make()`` would return, from its ``shape`` (each marker's
        action and point count), the ``stamp`` [ns] of every marker and, per marker, its pose
        position (x, y, z) and its points' coordinates (x, y, z, x, y, z, ...).  ``make`` is
        called only for a shape not seen yet (its template) or one that has none."""
        template = self._template_of(shape, make)
        if template is None:
            return serialize_message(make())
        data, offsets = template
        buf = bytearray(data)
        sec, nanosec = divmod(stamp, 1_000_000_000)
        pack_into = struct.pack_into
        for (stamp_at, pose_at, points_at), (pose, points) in zip(offsets, values):
            pack_into('<iI', buf, stamp_at, sec, nanosec)
            pack_into('<3d', buf, pose_at, *pose)
            if points_at >= 0:
                pack_into(f'<{len(points)}d', buf, points_at, *points)
        return bytes(buf)

    def _template_of(self, shape: tuple, make: Callable[[], Any]
                     ) -> tuple[bytes, list[tuple[int, int, int]]] | None:
        if shape not in self._templates:
            if len(self._templates) >= MAX_SHAPES:
                self._templates.clear()
            self._templates[shape] = self._template(make())
        return self._templates[shape]

    @staticmethod
    def _template(array: Any) -> tuple[bytes, list[tuple[int, int, int]]] | None:
        """The bytes of ``array`` with sentinels in its varying fields, and where they are."""
        probe = copy.deepcopy(array)
        k = 0
        for n, m in enumerate(probe.markers):
            m.header.stamp.sec, m.header.stamp.nanosec = _SEC0 + n, _NSEC0 + n
            for q in (m.pose.position, *m.points):
                q.x, q.y, q.z = _real(k), _real(k + 1), _real(k + 2)
                k += 3
        data = serialize_message(probe)
        offsets = []
        k = 0
        for n, m in enumerate(probe.markers):
            stamp_at = _find(data, struct.pack('<iI', _SEC0 + n, _NSEC0 + n))
            want = struct.pack(f'<{3 * (1 + len(m.points))}d',
                               *[_real(k + i) for i in range(3 * (1 + len(m.points)))])
            pose_at = _find(data, want[:24])
            points_at = _find(data, want[24:]) if m.points else -1
            k += len(want) // 8
            if stamp_at is None or pose_at is None or points_at is None:
                return None
            offsets.append((stamp_at, pose_at, points_at))
        return data, offsets
