"""The pendulum as visualization_msgs/MarkerArray (sim_nodes/ros/markers.py) over real Fast DDS:
the simulator's scene of every state (links, joints, cart or car, rail or hill, goal), the
policy node's ghost of the exemplar it used, nothing for a model without a drawing.  That the
markers are recorded is checked on the launch's bags (tests/test_recording_launch.py)."""
from __future__ import annotations

import threading

import numpy as np
import pytest
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from ros_helpers import PROBE_QOS, Probe, isolated_ros
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sim_nodes import geometry
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout, stamp_ns
from sim_nodes.ros.markers import PendulumMarkers
from sim_nodes.ros.sim_node import SimNode


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class MarkerProbe(Probe):
    """A Probe that also keeps every MarkerArray, by namespace of its first marker."""

    def __init__(self, problem, **kwargs) -> None:
        super().__init__(problem, **kwargs)
        self.arrays: list[MarkerArray] = []
        self._marker_lock = threading.Lock()
        self.create_subscription(MarkerArray, 'markers', self._on_markers, PROBE_QOS)

    def _on_markers(self, msg: MarkerArray) -> None:
        with self._marker_lock:
            self.arrays.append(msg)

    def by_ns(self, ns: str) -> dict[int, dict[str, Marker]]:
        """stamp [ns] -> {namespace: marker} of the arrays holding ``ns``."""
        with self._marker_lock:
            arrays = list(self.arrays)
        return {stamp_ns(a.markers[0]): {m.ns: m for m in a.markers}
                for a in arrays if any(m.ns == ns for m in a.markers)}


def arrays_before_a_sentinel(ros, sim: SimNode, probe: MarkerProbe) -> list[MarkerArray]:
    """The marker arrays the probe got from ``sim`` before a sentinel array that the test
    sends through the simulator's own marker publisher once the states seen so far are in.

    Every node of the harness runs in one executor thread, so the probe holding a state
    means the simulator has finished publishing it with its markers; one reliable DDS
    writer delivers in order, so an array published then arrives before the sentinel.
    """
    assert sim._marker_pub.get_subscription_count() == 1
    sentinel = Marker(ns='sentinel', id=len(probe.arrays))

    def index() -> int | None:
        with probe._marker_lock:
            return next((i for i, a in enumerate(probe.arrays) if a.markers[:1] == [sentinel]),
                        None)
    sim._marker_pub.publish(MarkerArray(markers=[sentinel]))
    ros.wait_for(lambda: index() is not None, 'the sentinel array')
    return [a for a in probe.arrays[:index()] if a.markers[0].ns != 'sentinel']


def xz(marker: Marker) -> list[tuple[float, float]]:
    assert all(p.y == 0.0 for p in marker.points)
    return [(p.x, p.z) for p in marker.points]


def segments(pic) -> list[tuple[float, float]]:
    return [p for seg in pic.links for p in seg]


@pytest.mark.parametrize('name', ['acrobot', 'pdip', 'mountain_car'])
def test_the_sim_draws_every_state_it_publishes(ros, name):
    """For each published state: one array stamped like it, in ros.frame_id, whose links,
    joints and body are the geometry of that state; the track and the goal come along."""
    problem = load_problem(name)
    layout = JointStateLayout(problem)
    probe = ros.start(MarkerProbe, problem=problem)
    sim = ros.start(SimNode, params={'problem': name, 'mode': 'lockstep',
                                     'republish_period': 0.05})
    ros.wait_for(lambda: sim._stamped_sub.get_publisher_count() and probe.states, 'discovery')
    tick = round(problem.dt * problem.substeps * 1e9)
    for k in range(5):
        probe.answer(problem.actions[-1], k * tick)
        ros.wait_for(lambda k=k: (k + 1) * tick in probe.states, f'state {k + 1}')
    key = 'body' if name == 'mountain_car' else 'links'
    scenes = ros.wait_for(lambda: len(probe.by_ns(key)) >= 6 and probe.by_ns(key), 'scenes')
    drawing = geometry.drawing(problem)
    for stamp, msg in list(probe.states.items()):
        scene = scenes[stamp]
        pic = geometry.picture(problem, layout.from_msg(msg))
        assert {m.header.frame_id for m in scene.values()} == {problem.ros['frame_id']}
        assert {stamp_ns(m) for m in scene.values()} == {stamp}
        if pic.links:
            assert scene['links'].type == Marker.LINE_LIST
            assert np.allclose(xz(scene['links']), segments(pic))
            assert np.allclose(xz(scene['joints']), pic.joints)
        if pic.body is not None:
            position = scene['body'].pose.position
            assert (position.x, position.z) == pytest.approx(pic.body)
            assert scene['body'].scale.x == drawing.body_size[0]
        if drawing.track is not None:
            assert np.allclose(xz(scene['track']), geometry.track(problem))
        goal = [geometry.picture(problem, s)
                for s in geometry.goal_states(problem, sim.settings.delta)]
        want = [p for g in goal for p in (segments(g) if pic.links else g.points)]
        assert np.allclose(xz(scene['goal']), want)


def test_a_model_without_a_drawing_publishes_no_markers(ros, monkeypatch):
    """The pendulum with its drawing removed: states as usual, no markers, no error."""
    monkeypatch.delitem(geometry.DRAWINGS, 'pendulum')
    problem = load_problem('pendulum')
    probe = ros.start(MarkerProbe, problem=problem)
    sim = ros.start(SimNode, params={'problem': 'pendulum', 'mode': 'lockstep',
                                     'republish_period': 0.05})
    ros.wait_for(lambda: sim._stamped_sub.get_publisher_count() and probe.states, 'discovery')
    probe.answer(1.0, 0)
    ros.wait_for(lambda: len(probe.states) == 2, 'a step')
    assert arrays_before_a_sentinel(ros, sim, probe) == []


def test_markers_false_publishes_none(ros):
    problem = load_problem('acrobot')
    probe = ros.start(MarkerProbe, problem=problem)
    sim = ros.start(SimNode, params={'mode': 'lockstep', 'republish_period': 0.05,
                                     'markers': False})
    ros.wait_for(lambda: len(probe.states) == 1, 'the first state')
    assert arrays_before_a_sentinel(ros, sim, probe) == []
    # the same wait sees markers once they are on: the check above can fail
    sim.set_parameters([Parameter('markers', value=True)])
    probe.answer(1.0, 0)
    ros.wait_for(lambda: len(probe.states) == 2, 'a step')
    assert len(arrays_before_a_sentinel(ros, sim, probe)) >= 1


def test_the_policy_node_draws_the_exemplar_it_used(ros, tmp_path):
    """Each answer comes with the ghost of the exemplar reported on exemplar_index, stamped
    with the answered state's stamp."""
    problem = load_problem('acrobot')
    layout = JointStateLayout(problem)
    rng = np.random.default_rng(8)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (30, 4)),
                            rng.integers(0, 3, 30))
    policy.save(tmp_path / 'p.json')
    probe = ros.start(MarkerProbe, problem=problem)
    pol = ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'p.json')})
    ros.wait_for(lambda: pol._state_sub.get_publisher_count()
                 and pol._marker_pub.get_subscription_count(), 'discovery')
    for k, s in enumerate(rng.uniform(problem.low, problem.high, (5, 4)), 1):
        probe.state_pub.publish(layout.to_msg(s, 0.0, k))
    ros.wait_for(lambda: len(probe.indices) == 5 and len(probe.by_ns('exemplar')) == 5,
                 'five answers and ghosts')
    ghosts = probe.by_ns('exemplar')
    assert sorted(ghosts) == sorted(probe.answered) == [1, 2, 3, 4, 5]
    for stamp, j in zip(probe.answered, probe.indices):
        ghost = ghosts[stamp]['exemplar']
        assert ghost.action == Marker.ADD and ghost.header.frame_id == 'acrobot'
        want = segments(geometry.picture(problem, policy.states[j]))
        assert np.allclose(xz(ghost), want)


def test_no_exemplar_deletes_the_ghost():
    """Exemplar index -1 (none used): the ghost marker is deleted, not left standing."""
    markers = PendulumMarkers(load_problem('pdip'))
    shown = markers.exemplar(np.zeros(6), 7).markers[0]
    assert shown.action == Marker.ADD and len(shown.points) == 4
    gone = markers.exemplar(None, 8).markers[0]
    assert gone.action == Marker.DELETE and stamp_ns(gone) == 8 and gone.ns == 'exemplar'
