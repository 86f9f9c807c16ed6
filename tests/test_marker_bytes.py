"""MarkerBytes: patched serializations decode to the messages rclpy serializes itself."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import MarkerArray

from sim_nodes.problem import load_problem
from sim_nodes.ros.marker_bytes import MarkerBytes
from sim_nodes.ros.markers import PendulumMarkers

PROBLEMS = ['acrobot', 'acrobot_hold', 'pendulum', 'pdip', 'pdip_single', 'pdip_hold',
            'mountain_car']


def _decoded(data: bytes) -> MarkerArray:
    return deserialize_message(data, MarkerArray)


@pytest.mark.parametrize('name', PROBLEMS)
def test_patched_bytes_decode_as_serialize_message(name):
    problem = load_problem(name)
    markers = PendulumMarkers(problem)
    assert markers.enabled
    fast = MarkerBytes()
    rng = np.random.default_rng(3)
    for k in range(60):
        s = rng.uniform(problem.low, problem.high)
        stamp = int(rng.integers(0, 2 ** 60))
        scene = markers.state(s, stamp, (0.02, 0.1)[k % 2])   # goal band changes too
        assert _decoded(fast.bytes_of(scene)) == _decoded(serialize_message(scene))
        ghost = markers.exemplar(None if k % 5 == 0 else s, stamp + 1)   # DELETE and ADD
        assert _decoded(fast.bytes_of(ghost)) == _decoded(serialize_message(ghost))
    assert all(t is not None for t in fast._templates.values())   # no ordinary fallback


@pytest.mark.parametrize('name', PROBLEMS)
def test_bytes_made_without_messages_equal_the_patched_message(name):
    """state_bytes / exemplar_bytes (no Point messages) give byte for byte what bytes_of
    gives for the drawn message with the same templates (CDR padding is whatever the
    template's serialization left there), whatever the state, stamp and goal band."""
    problem = load_problem(name)
    markers, drawn = PendulumMarkers(problem), PendulumMarkers(problem)
    fast = slow = MarkerBytes()
    rng = np.random.default_rng(5)
    for k in range(60):
        s = rng.uniform(problem.low, problem.high)
        stamp = int(rng.integers(0, 2 ** 60))
        delta = (0.02, 0.1, 0.05)[k % 3]
        data = markers.state_bytes(s, stamp, delta, fast)
        assert data == slow.bytes_of(drawn.state(s, stamp, delta))
        assert _decoded(data) == _decoded(serialize_message(drawn.state(s, stamp, delta)))
        ghost_state = None if k % 4 == 0 else s
        ghost = markers.exemplar_bytes(ghost_state, stamp + 7, fast)
        assert ghost == slow.bytes_of(drawn.exemplar(ghost_state, stamp + 7))
    assert all(t is not None for t in fast._templates.values())
