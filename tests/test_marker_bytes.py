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
