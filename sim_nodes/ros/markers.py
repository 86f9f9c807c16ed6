"""The pendulum as ``visualization_msgs/MarkerArray`` for Foxglove's 3D panel and RViz.

The geometry is ``sim_nodes.geometry`` (pure); here it becomes markers in the frame
``ros.frame_id`` of the problem, in the x-z plane (x along the rail, z up), each stamped with
the stamp of the state drawn.  Every array is complete (static parts included), so a viewer
that joins late, or plays a recording from its middle, draws the whole scene.

==========  ===================  =============================================  ==========
namespace   type                 what                                           published
==========  ===================  =============================================  ==========
links       LINE_LIST            the links / poles of the current state         simulator
joints      SPHERE_LIST          pivots, elbows, tips                           simulator
body        CUBE / SPHERE        the cart (PDIP) or the car (mountain car)      simulator
track       LINE_STRIP           the rail or the hill                           simulator
goal        LINE_LIST /          the best state and the edges of the S_delta    simulator
            SPHERE_LIST          band (``geometry.goal_states``), translucent
exemplar    LINE_LIST /          the state of the exemplar the policy used      policy node
            SPHERE_LIST          (deleted while it used none)
==========  ===================  =============================================  ==========

A model without a drawing gets no markers (``enabled`` false): not an error.
"""
from __future__ import annotations

from typing import Sequence

from geometry_msgs.msg import Point as PointMsg
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from sim_nodes import geometry
from sim_nodes.geometry import Picture, Point
from sim_nodes.problem import Problem
from sim_nodes.ros.common import set_stamp
from sim_nodes.ros.marker_bytes import MarkerBytes

LINE_WIDTH = 0.04           # [m] links
JOINT_SIZE = 0.08           # [m] sphere diameter
TRACK_WIDTH = 0.02          # [m]
DEPTH = 0.2                 # [m] the cart's extent along y
COLORS = {'links': (0.16, 0.38, 0.75, 1.0), 'joints': (0.1, 0.1, 0.1, 1.0),
          'body': (0.3, 0.3, 0.3, 1.0), 'track': (0.5, 0.5, 0.5, 1.0),
          'goal': (0.1, 0.7, 0.2, 0.45), 'exemplar': (1.0, 0.55, 0.0, 0.6)}


def _points(points: Sequence[Point]) -> list[PointMsg]:
    return [PointMsg(x=float(x), y=0.0, z=float(z)) for x, z in points]


def _link_points(pictures: Sequence[Picture]) -> list[Point]:
    """Both ends of every link of ``pictures``, in order (a LINE_LIST's points)."""
    return [p for pic in pictures for seg in pic.links for p in seg]


def _segments(pictures: Sequence[Picture]) -> list[PointMsg]:
    return _points(_link_points(pictures))


def _flat(points: Sequence[Point]) -> list[float]:
    """x, y, z of each point as ``_points`` makes them, one flat list."""
    return [c for x, z in points for c in (float(x), 0.0, float(z))]


ORIGIN = (0.0, 0.0, 0.0)


class PendulumMarkers:
    """MarkerArrays of one problem's states (``state``) and exemplar ghosts (``exemplar``)."""

    def __init__(self, problem: Problem) -> None:
        self.problem = problem
        self.drawing = geometry.drawing(problem)
        self.enabled = self.drawing is not None
        self.frame_id = str(problem.ros.get('frame_id', problem.name))
        if not self.enabled:
            return
        sample = geometry.picture(problem, problem.initial_state)
        self._lines = bool(sample.links)    # pose sets drawn as lines, else as points
        self._links = self._marker('links', Marker.LINE_LIST, LINE_WIDTH) if sample.links \
            else None
        self._joints = self._marker('joints', Marker.SPHERE_LIST, JOINT_SIZE) \
            if sample.joints else None
        self._body = None
        if sample.body is not None:
            width, height = self.drawing.body_size
            if self.drawing.body_shape == 'cube':
                self._body = self._marker('body', Marker.CUBE, width)
                self._body.scale.y, self._body.scale.z = DEPTH, height
            else:
                self._body = self._marker('body', Marker.SPHERE, width)
        rail = geometry.track(problem)
        self._track = None
        if rail:
            self._track = self._marker('track', Marker.LINE_STRIP, TRACK_WIDTH)
            self._track.points = _points(rail)
        self._track_flat = _flat(rail) if rail else []
        self._goal = self._pose_marker('goal')
        self._goal_delta: float | None = None
        self._goal_flat: list[float] = []
        self._ghost = self._pose_marker('exemplar')
        self._ghost_array = MarkerArray(markers=[self._ghost])

    def _marker(self, ns: str, kind: int, size: float) -> Marker:
        m = Marker(ns=ns, id=0, type=kind, action=Marker.ADD)
        m.header.frame_id = self.frame_id
        m.scale.x = m.scale.y = m.scale.z = size
        m.color = ColorRGBA(r=COLORS[ns][0], g=COLORS[ns][1], b=COLORS[ns][2], a=COLORS[ns][3])
        return m

    def _pose_marker(self, ns: str) -> Marker:
        """A marker drawing whole poses: their links, or their points for a model without."""
        if self._lines:
            return self._marker(ns, Marker.LINE_LIST, LINE_WIDTH)
        return self._marker(ns, Marker.SPHERE_LIST, 1.5 * JOINT_SIZE)

    def _pose_points(self, pictures: Sequence[Picture]) -> list[PointMsg]:
        return _points(self._pose_xz(pictures))

    def _pose_xz(self, pictures: Sequence[Picture]) -> list[Point]:
        if self._lines:
            return _link_points(pictures)
        return [p for pic in pictures for p in pic.points]

    def _set_goal(self, delta: float) -> None:
        if delta != self._goal_delta:
            self._goal_delta = delta
            xz = self._pose_xz([geometry.picture(self.problem, g)
                                for g in geometry.goal_states(self.problem, delta)])
            self._goal.points = _points(xz)
            self._goal_flat = _flat(xz)

    def state(self, s: Sequence[float], stamp: int, delta: float) -> MarkerArray | None:
        """The scene of state ``s`` stamped ``stamp`` [ns], the goal band at ``delta``; None
        when the model has no drawing."""
        if not self.enabled:
            return None
        pic = geometry.picture(self.problem, s)
        self._set_goal(delta)
        if self._links is not None:
            self._links.points = _segments([pic])
        if self._joints is not None:
            self._joints.points = _points(pic.joints)
        if self._body is not None:
            self._body.pose.position.x, self._body.pose.position.z = pic.body
        markers = [m for m in (self._links, self._joints, self._body, self._track, self._goal)
                   if m is not None]
        for m in markers:
            set_stamp(m.header, stamp)
        return MarkerArray(markers=markers)

    def state_bytes(self, s: Sequence[float], stamp: int, delta: float,
                    packer: MarkerBytes) -> bytes | None:
        """``packer.bytes_of(self.state(s, stamp, delta))``, made without messages."""
        if not self.enabled:
            return None
        pic = geometry.picture(self.problem, s)
        self._set_goal(delta)
        values = []
        if self._links is not None:
            values.append((ORIGIN, _flat(_link_points([pic]))))
        if self._joints is not None:
            values.append((ORIGIN, _flat(pic.joints)))
        if self._body is not None:
            values.append(((float(pic.body[0]), 0.0, float(pic.body[1])), ()))
        if self._track is not None:
            values.append((ORIGIN, self._track_flat))
        values.append((ORIGIN, self._goal_flat))
        shape = tuple((Marker.ADD, len(points) // 3) for _, points in values)
        return packer.patched(shape, lambda: self.state(s, stamp, delta), stamp, values)

    def exemplar_bytes(self, s: Sequence[float] | None, stamp: int,
                       packer: MarkerBytes) -> bytes | None:
        """``packer.bytes_of(self.exemplar(s, stamp))``, made without messages."""
        if not self.enabled:
            return None
        points = [] if s is None else _flat(self._pose_xz([geometry.picture(self.problem, s)]))
        shape = ((Marker.DELETE, 0),) if s is None else ((Marker.ADD, len(points) // 3),)
        return packer.patched(shape, lambda: self.exemplar(s, stamp), stamp,
                              [(ORIGIN, points)])

    def exemplar(self, s: Sequence[float] | None, stamp: int) -> MarkerArray | None:
        """The ghost of the exemplar state ``s`` stamped ``stamp`` [ns] (``s`` None: delete
        it); None when the model has no drawing."""
        if not self.enabled:
            return None
        ghost = self._ghost
        set_stamp(ghost.header, stamp)
        if s is None:
            ghost.action, ghost.points = Marker.DELETE, []
        else:
            ghost.action = Marker.ADD
            ghost.points = self._pose_points([geometry.picture(self.problem, s)])
        return self._ghost_array
