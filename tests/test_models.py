"""Properties of the dynamics kernels (sim_nodes/models; SPEC 2.1, 2.2): conservation laws,
equilibria, bounds, the rail rule, the pdip_single symmetry, and agreement with the plain
NumPy statement of the same equations (sim_nodes/reference.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim_nodes import reference
from sim_nodes.models import acrobot, model_module, pdip
from sim_nodes.models.common import TWO_PI, wrap_angle

HALF_PI, THREE_HALF_PI = math.pi / 2, 3 * math.pi / 2


def circular_abs_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b|_c elementwise: the short way round the circle."""
    d = np.abs(np.asarray(a) - np.asarray(b)) % TWO_PI
    return np.minimum(d, TWO_PI - d)


def state_error(problem, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Coordinate-wise |a - b|, circular on the angles."""
    err = np.abs(a - b)
    err[..., problem.is_angle] = circular_abs_diff(a[..., problem.is_angle],
                                                   b[..., problem.is_angle])
    return err


def run_lanes(problem, states: np.ndarray, actions: np.ndarray):
    """Advance states (W, D) through actions (T, W) with mdp_step_lanes: (T, W, D), (T, W)."""
    step_lanes = model_module(problem.model).mdp_step_lanes
    p = problem.params()
    S = np.ascontiguousarray(states.T)
    reward = np.empty(S.shape[1])
    out_s = np.empty((len(actions), *states.shape))
    out_r = np.empty(actions.shape)
    for t, a in enumerate(actions):
        step_lanes(S, np.ascontiguousarray(a, dtype=np.float64), p, S.shape[1], reward)
        out_s[t] = S.T
        out_r[t] = reward
    return out_s, out_r


def random_states(problem, rng, count: int) -> np.ndarray:
    """States uniform over the problem's bounds (velocities up to their clip bounds)."""
    return rng.uniform(problem.low, problem.high, (count, problem.dim))


# --- acrobot ----------------------------------------------------------------------------

ENERGY_STARTS = [  # (theta1, theta2, theta1_dot, theta2_dot): swinging, far from the clips
    (HALF_PI + 1.0, 0.5, 0.3, -0.4),
    (THREE_HALF_PI + 1.2, 5.5, -1.0, 2.0),
    (0.3, 2.0, 0.5, 0.5),
]


@pytest.mark.parametrize('start', ENERGY_STARTS)
def test_acrobot_rk4_conserves_energy_without_torque(acrobot_problem, start):
    """With zero torque and no clipping, RK4 keeps the total energy to 1e-6 (relative) for
    1 s = 20 MDP steps.

    The relative drift is taken against the potential-energy span from hanging to upright,
    2 g (m1 lc1 + m2 l1 + m2 lc2) = 39.2 J: E itself depends on where heights are measured
    from and may be near 0, while this span is the energy scale of a swing-up.  Each start
    also has |E(0)| > 5 J, so the bound holds relative to |E(0)| within a factor of 8.
    """
    phys = acrobot_problem.physics
    p = acrobot_problem.params()
    span = 2 * phys['g'] * (phys['m1'] * phys['lc1'] + phys['m2'] * phys['l1']
                            + phys['m2'] * phys['lc2'])
    s = np.array(start, dtype=np.float64)
    e0 = acrobot.energy(s, p)
    assert abs(e0) > 5.0
    drift, w_max = 0.0, np.zeros(2)
    for _ in range(20):
        acrobot.mdp_step(s, 0.0, p)
        drift = max(drift, abs(acrobot.energy(s, p) - e0))
        w_max = np.maximum(w_max, np.abs(s[2:]))
    # the clips never acted, so the test measures the integrator alone
    assert np.all(w_max < 0.5 * np.array([phys['max_theta1_dot'], phys['max_theta2_dot']]))
    assert drift / span < 1e-6
    assert drift / abs(e0) < 1e-6


def test_acrobot_torque_changes_the_energy(acrobot_problem):
    """The energy check above is sensitive: holding the elbow torque does work on the
    links and moves E by far more than the conservation tolerance."""
    p = acrobot_problem.params()
    s = np.array(ENERGY_STARTS[0])
    e0 = acrobot.energy(s, p)
    for _ in range(20):
        acrobot.mdp_step(s, 2.0, p)
    assert abs(acrobot.energy(s, p) - e0) > 1e-2


def test_acrobot_hanging_state_is_an_equilibrium(acrobot_problem):
    """Hanging straight down at rest with zero torque stays put for a whole episode (400
    steps), to rounding; its reward is the minimum, -5."""
    p = acrobot_problem.params()
    s0 = acrobot_problem.initial_state
    assert np.array_equal(s0, [THREE_HALF_PI, 0, 0, 0])
    s = s0.copy()
    for _ in range(400):
        reward = acrobot.mdp_step(s, 0.0, p)
    assert np.all(state_error(acrobot_problem, s, s0) < 1e-12)
    assert reward == pytest.approx(-5.0, abs=1e-12)


def test_acrobot_upright_state_is_an_equilibrium(acrobot_problem):
    """Upright at rest with zero torque stays put to rounding over 1 s (20 steps); it is
    unstable, so rounding errors grow after that.  Its reward is the maximum, -1."""
    p = acrobot_problem.params()
    s0 = acrobot_problem.best_state
    assert np.array_equal(s0, [HALF_PI, 0, 0, 0])
    s = s0.copy()
    for _ in range(20):
        reward = acrobot.mdp_step(s, 0.0, p)
    assert np.all(state_error(acrobot_problem, s, s0) < 1e-12)
    assert reward == pytest.approx(-1.0, abs=1e-12)


def test_pdip_hanging_state_is_an_equilibrium(pdip_problem):
    """The PDIP at rest with both poles down and no force stays put for 400 steps."""
    p = pdip_problem.params()
    s0 = pdip_problem.initial_state
    s = s0.copy()
    for _ in range(400):
        reward = pdip.mdp_step(s, 0.0, p)
    assert np.all(state_error(pdip_problem, s, s0) < 1e-12)
    assert reward == pytest.approx(-5.0, abs=1e-12)


def velocity_bounds(problem) -> np.ndarray:
    """Clip bound of every coordinate (inf for positions)."""
    phys = problem.physics
    if problem.model == 'acrobot':
        return np.array([np.inf, np.inf, phys['max_theta1_dot'], phys['max_theta2_dot']])
    w = phys['theta_dot_max']
    return np.array([phys['x_max'], phys['v_max'], np.inf, np.inf, w, w])


def test_state_stays_within_bounds_under_max_actions(problem, rng):
    """Under bang-bang extreme actions from states anywhere in the bounds (velocities up to
    the clips), velocities never leave their clip bounds, angles stay in [0, 2pi) and the
    cart on its rail, for 400 steps; and the clips actually act."""
    count, steps = 64, 400
    states = random_states(problem, rng, count)
    extreme = np.array([min(problem.actions), max(problem.actions)])
    actions = extreme[rng.integers(0, 2, (steps, count))]
    traj, _ = run_lanes(problem, states, actions)
    bound = velocity_bounds(problem)
    assert np.all(np.abs(traj) <= bound)
    angles = traj[..., problem.is_angle]
    assert np.all((angles >= 0.0) & (angles < TWO_PI))
    clipped = np.isfinite(bound) & ~problem.is_angle
    assert np.any(np.abs(traj[..., clipped]) == bound[clipped])  # the clip was reached


def test_wrap_angle_lands_in_zero_to_two_pi():
    """wrap_angle maps any angle into [0, 2pi), also a tiny negative one whose exact wrap
    rounds to 2pi, and keeps angles already in range unchanged."""
    for theta in (-1e-20, -1e-300, -0.0, TWO_PI, -TWO_PI, 7 * TWO_PI + 1.0, -1e5, 1e5):
        w = wrap_angle(theta)
        assert 0.0 <= w < TWO_PI
        assert circular_abs_diff(w, theta) < 1e-9
    for theta in (0.0, 1.0, HALF_PI, np.nextafter(TWO_PI, 0.0)):
        assert wrap_angle(theta) == theta


def test_wrap_angle_of_a_negative_subnormal_is_in_range():
    """wrap_angle of a negative angle so small that theta / 2pi underflows to -0 (|theta|
    below about 1.5e-323) still lands in [0, 2pi)."""
    for theta in (-5e-324, -1e-323):
        assert 0.0 <= wrap_angle(theta) < TWO_PI


# --- kernels against the NumPy reference ------------------------------------------------

def test_mdp_step_agrees_with_the_numpy_reference(problem, rng):
    """One compiled MDP step equals sim_nodes.reference's step to 1e-12 from random states
    and actions (the two differ only in sin/cos and in algebraically equal forms); for the
    PDIP the sample includes rail hits, and both agree on which steps hit."""
    module = model_module(problem.model)
    ref_step = reference.STEPS[problem.model]
    p = problem.params()
    states = random_states(problem, rng, 2000)
    actions = np.array(problem.actions)[rng.integers(0, len(problem.actions), len(states))]
    rail_hits = 0
    for s0, a in zip(states, actions):
        s = s0.copy()
        reward = module.mdp_step(s, a, p)
        ref_s, ref_reward = ref_step(s0, a, problem)
        scale = np.maximum(1.0, np.abs(ref_s))
        assert np.all(state_error(problem, s, ref_s) <= 1e-12 * scale), (s0, a)
        assert reward == pytest.approx(ref_reward, abs=1e-12), (s0, a)
        rail_hits += reward < -50.0
    if problem.model == 'pdip':
        assert rail_hits > 100


def test_lanes_are_bit_identical_to_scalar_steps(problem, rng):
    """mdp_step_lanes on W lanes gives exactly (==) the states and rewards of W separate
    scalar mdp_step calls, step after step (no reassociation, no FMA in the batch)."""
    count, steps = 37, 50
    module = model_module(problem.model)
    p = problem.params()
    states = random_states(problem, rng, count)
    actions = np.array(problem.actions)[rng.integers(0, len(problem.actions), (steps, count))]
    traj, rewards = run_lanes(problem, states, actions)
    for k in range(count):
        s = states[k].copy()
        for t in range(steps):
            r = module.mdp_step(s, actions[t, k], p)
            assert np.array_equal(s, traj[t, k]) and r == rewards[t, k], (k, t)


def test_lanes_beyond_n_are_left_untouched(problem, rng):
    """mdp_step_lanes advances only columns 0..n-1 and writes only reward[:n]."""
    module = model_module(problem.model)
    S = np.ascontiguousarray(random_states(problem, rng, 8).T)
    before = S.copy()
    reward = np.full(8, 123.0)
    module.mdp_step_lanes(S, np.full(8, max(problem.actions)), problem.params(), 5, reward)
    assert np.array_equal(S[:, 5:], before[:, 5:]) and np.all(reward[5:] == 123.0)
    assert not np.array_equal(S[:, :5], before[:, :5])


# --- PDIP rail rule and symmetry ---------------------------------------------------------

@pytest.mark.parametrize('force', [40.0, -40.0])
def test_rail_stops_the_cart_at_its_end_with_the_penalty(pdip_problem, force):
    """Pushing one way for long enough stops the cart at x = +-2.5 exactly with v = 0, and
    that MDP step's reward is sin th1 + sin th2 - 3 - 100; steps before it carry no
    penalty, and pushing on keeps the cart at the rail end, penalised every step."""
    p = pdip_problem.params()
    x_max = pdip_problem.physics['x_max']
    s = pdip_problem.initial_state.copy()
    for step in range(1, 41):
        reward = pdip.mdp_step(s, force, p)
        if abs(s[0]) == x_max:
            break
        assert -5.0 <= reward <= -1.0 and abs(s[0]) < x_max
    else:
        pytest.fail('the cart never reached the rail end')
    assert step > 1
    assert s[0] == math.copysign(x_max, force) and s[1] == 0.0
    assert reward == pytest.approx(math.sin(s[2]) + math.sin(s[3]) - 3.0 - 100.0, abs=1e-12)
    for _ in range(5):
        reward = pdip.mdp_step(s, force, p)
        assert s[0] == math.copysign(x_max, force) and s[1] == 0.0
        assert reward == pytest.approx(math.sin(s[2]) + math.sin(s[3]) - 103.0, abs=1e-12)


def test_rail_penalty_counts_once_per_mdp_step(pdip_problem):
    """A step whose substeps hit the rail several times is penalised -100 once: its reward
    stays within the pole-height range shifted by -100, i.e. in [-105, -101]."""
    p = pdip_problem.params()
    s = np.array([2.5, 16.0, HALF_PI, HALF_PI, 0.0, 0.0])  # at the end, driving into it
    reward = pdip.mdp_step(s, 40.0, p)
    assert s[0] == 2.5 and -105.0 <= reward <= -101.0


def test_pdip_single_poles_move_identically(pdip_single_problem, rng):
    """With l2 = l1 and the symmetric start, theta1 == theta2 and theta1_dot == theta2_dot
    exactly (==) at every one of 400 steps, whatever the force sequence."""
    count, steps = 16, 400
    states = np.repeat(pdip_single_problem.initial_state[None], count, axis=0)
    actions = np.array(pdip_single_problem.actions)[rng.integers(0, 3, (steps, count))]
    traj, _ = run_lanes(pdip_single_problem, states, actions)
    assert np.array_equal(traj[..., 2], traj[..., 3])
    assert np.array_equal(traj[..., 4], traj[..., 5])
    assert np.ptp(traj[..., 2]) > 1.0  # the poles did swing


def test_pdip_poles_of_different_lengths_move_apart(pdip_problem, rng):
    """With l2 = 0.5 != l1 the same force sequences drive the two poles apart: the pdip is
    not the single pendulum."""
    count, steps = 16, 400
    states = np.repeat(pdip_problem.initial_state[None], count, axis=0)
    actions = np.array(pdip_problem.actions)[rng.integers(0, 3, (steps, count))]
    traj, _ = run_lanes(pdip_problem, states, actions)
    apart = circular_abs_diff(traj[..., 2], traj[..., 3]).max(axis=0)
    assert np.all(apart > 0.1)
