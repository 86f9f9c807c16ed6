"""Disturbed episodes: the counter-based random draws and what they do to one episode.

Every draw is a pure function of its key, never of a generator's history: an episode is keyed
by (seed, generation, policy, episode) (``episode_key``), and each draw inside it by a stream
(what is drawn) and a counter (which one), hashed with the SplitMix64 finaliser.  A disturbed
episode therefore does not depend on which thread, worker, batch or backend runs it, nor on
what ran before it: runs are reproducible, resumable and identical for any worker count.

``dist`` is a profile packed for one problem (``sim_nodes.disturbance.Disturbance.pack``;
``OFF`` entries at index ``ON``: undisturbed).  The kernels here are what the episode engine
(``sapga_ros.evaluation.engine``) and the simulator node call at the start of an episode
(``start_episode``) and at each step (``observe``, ``command``, ``push``).
"""
import math

import numpy as np

from sim_nodes.jit import kernel
from sim_nodes.models.common import wrap_angle

# packed profile: [on, latency, gain, pushes, push size, mismatch on,
#                  spread (D), sigma (D), push mask (D), mismatch (len p)]
ON, LATENCY, GAIN, PUSHES, PUSH_SIZE, MISMATCH, HEAD = range(7)
OFF = np.zeros(HEAD)                      # the undisturbed profile
# the ``policy`` slot of a key: every policy of a training run meets the same draws
# (TRAINING), evaluations and the simulator node draw episodes training never saw (HELD_OUT)
TRAINING, HELD_OUT = 0, 1
# streams: what a draw is for
S_INITIAL, S_PARAMS, S_GAIN, S_PUSH, S_NOISE = range(5)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_UNIT = 1.0 / 9007199254740992.0          # 2^-53


@kernel
def _mix(z):
    """The SplitMix64 finaliser (a bijection of 64-bit words with full avalanche)."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@kernel
def episode_key(seed, generation, policy, episode):
    """The 64-bit key of one episode's draws."""
    h = _mix(np.uint64(seed) + _GOLDEN)
    h = _mix(h ^ np.uint64(generation))
    h = _mix(h ^ np.uint64(policy) + _GOLDEN)
    return _mix(h ^ np.uint64(episode))


@kernel
def uniform(key, stream, counter):
    """Draw ``counter`` of ``stream`` under episode ``key``: a float in [0, 1).  (The key
    is made a 64-bit unsigned word first: from Python a key below 2^63 arrives as int64.)"""
    h = _mix(_mix(np.uint64(key) ^ (np.uint64(stream) * _GOLDEN)) + np.uint64(counter))
    return float(h >> np.uint64(11)) * _UNIT


@kernel
def normal(key, stream, counter):
    """A standard normal draw (Box-Muller on draws 2 counter and 2 counter + 1)."""
    u1 = uniform(key, stream, 2 * counter)
    u2 = uniform(key, stream, 2 * counter + 1)
    return math.sqrt(-2.0 * math.log(1.0 - u1)) * math.cos(2.0 * math.pi * u2)


@kernel
def symmetric(key, stream, counter, size):
    """Uniform in [-size, size] (exactly 0 for size 0)."""
    return size * (2.0 * uniform(key, stream, counter) - 1.0)


@kernel
def start_episode(dist, key, s0, p, is_angle, n_step, s, q, push_at, push_dv, push_on):
    """Draw one episode's disturbances: the initial state ``s`` (s0 + spread), the plant's
    parameters ``q`` (p x mismatch factors), the push schedule (``push_at`` steps, velocity
    change ``push_dv`` on coordinate ``push_on``); return the actuator gain."""
    dim = s0.shape[0]
    for i in range(dim):
        s[i] = s0[i] + symmetric(key, S_INITIAL, i, dist[HEAD + i])
        if is_angle[i] and dist[HEAD + i] > 0.0:
            s[i] = wrap_angle(s[i])
    for i in range(p.shape[0]):
        q[i] = p[i] * (1.0 + symmetric(key, S_PARAMS, i, dist[HEAD + 3 * dim + i]))
    mask = dist[HEAD + 2 * dim:HEAD + 3 * dim]
    eligible = int(mask.sum())
    for j in range(push_at.shape[0]):
        push_at[j] = int(uniform(key, S_PUSH, 3 * j) * n_step)
        push_dv[j] = symmetric(key, S_PUSH, 3 * j + 1, dist[PUSH_SIZE])
        pick = int(uniform(key, S_PUSH, 3 * j + 2) * eligible)
        for i in range(dim):
            if mask[i] > 0.0:
                if pick == 0:
                    push_on[j] = i
                pick -= 1
    return 1.0 + symmetric(key, S_GAIN, 0, dist[GAIN])


@kernel
def observe(dist, key, step, s, is_angle, o):
    """What the selector sees at ``step``: o = s + Gaussian sensor noise (angles wrapped)."""
    dim = s.shape[0]
    for i in range(dim):
        sigma = dist[HEAD + dim + i]
        o[i] = s[i] + sigma * normal(key, S_NOISE, step * dim + i)
        if is_angle[i] and sigma > 0.0:
            o[i] = wrap_angle(o[i])


@kernel
def command(history, step, selected, gain):
    """The actuator's value at ``step``: the action selected ``latency`` steps before
    (``history`` holds latency + 1 of them; 0 before the first arrives) times ``gain``."""
    slots = history.shape[0]
    history[step % slots] = selected
    late = step - (slots - 1)
    return (history[late % slots] if late >= 0 else 0.0) * gain


@kernel
def push(step, push_at, push_dv, push_on, s):
    """Apply the pushes drawn for ``step`` to the state ``s`` (a velocity change)."""
    for j in range(push_at.shape[0]):
        if push_at[j] == step:
            s[push_on[j]] += push_dv[j]
