"""A second physics engine: the acrobot and the carts as MuJoCo models (no ROS here).

``MujocoPlant(problem)`` builds an MJCF model from the problem YAML's ``physics`` (masses,
lengths, inertias, gravity) and steps it with MuJoCo's own RK4 integrator (``timestep`` =
the problem's ``dt``; one MDP step holds the effort for ``substeps`` steps);
``set_physics(p)`` rebuilds it with other physics (a disturbance's drawn model error),
``place(s, before)`` writes a problem state's changed coordinates into its joints (a push)
and ``seen_joints`` adds a sensor's noise to what its joints report.  It speaks like a robot
that is not ours: its own joint names, its own angle zero and direction, efforts in its own
joint coordinates (one per actuator, ros2_control's forward command convention).

===========  =================  ==========================================================
model        robot joints       convention (MJCF: zero hanging down, hinge axis +y)
===========  =================  ==========================================================
acrobot      shoulder, elbow    theta1 = 3pi/2 - shoulder, theta2 = -elbow; actuator on
                                elbow: elbow effort = -(the problem's torque)
pdip         slider, hinge1,    x = slider, theta_i = 3pi/2 - hinge_i; actuator on slider:
             hinge2             effort = the problem's force; the rail is the slider's
                                joint limit [-x_max, x_max] (MuJoCo's soft constraint)
pdip, l1=l2  slider, hinge      one pole of mass m1 + m2 and half-length l1 (the same
(pdip_single)                   dynamics as two equal poles); theta1 = theta2 = 3pi/2 - hinge
===========  =================  ==========================================================

``CONVENTIONS[model]`` holds that table as data: ``mapping(problem)`` gives, for each of the
problem's ``ros.joints``, (robot joint, offset, direction) with problem coordinate =
offset + direction * robot coordinate, the mapping the policy node's parameters take.

The acrobot's links carry the given I1, I2 about their centres of mass (``diaginertia``:
not uniform-rod values); the PDIP's poles are uniform rods of half-length l_i (inertia
m l^2 / 3 about the centre: the kernel's 4/3 l factor).  Differences from the kernel, the
reason the two agree only over short horizons: MuJoCo's RK4 vs the kernel's integrators
(RK4 for the acrobot with clipping after each substep, semi-implicit Euler for the PDIP),
no velocity clipping here (a real joint has none), a soft joint limit instead of the
kernel's rail rule (stop the cart, zero its velocity), and chaotic dynamics that grow any
difference exponentially.  ``problem_state`` maps the robot's joints back to the problem's
coordinates (angles wrapped), for the simulator's reward, goal and markers; ``reward`` is
the kernel's own reward formula on that state (a zero-substep kernel step) plus the rail
penalty on a joint-limit contact.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim_nodes.errors import ConfigError
from sim_nodes.models import model_module
from sim_nodes.problem import Problem

TWO_PI = 2.0 * math.pi
DOWN = 1.5 * math.pi          # the problem's hanging-down angle


@dataclass(frozen=True)
class JointMap:
    """One of the problem's joints on the robot: coordinate = offset + direction * robot's."""

    robot_joint: str
    offset: float
    direction: float


def coordinates(problem: Problem) -> list[tuple[str, float, float, bool, bool]]:
    """Per coordinate of the problem's state: (robot joint, offset (0 for a velocity),
    direction, angle, velocity), so that coordinate = offset + direction * the joint's
    position or velocity (an angle wrapped to [0, 2pi))."""
    joints = mapping(problem)
    return [(joints[c.joint].robot_joint,
             joints[c.joint].offset if c.field == 'position' else 0.0,
             joints[c.joint].direction, c.angle, c.field == 'velocity')
            for c in problem.state]


def _single(problem: Problem) -> bool:
    return problem.model == 'pdip' and problem.physics['l1'] == problem.physics['l2']


def mapping(problem: Problem) -> dict[str, JointMap]:
    """The MuJoCo robot's joint for each of the problem's ``ros.joints`` (module table)."""
    if problem.model == 'acrobot':
        return {'shoulder': JointMap('shoulder', DOWN, -1.0),
                'elbow': JointMap('elbow', 0.0, -1.0)}
    if problem.model == 'pdip':
        poles = ('hinge', 'hinge') if _single(problem) else ('hinge1', 'hinge2')
        return {'cart': JointMap('slider', 0.0, 1.0),
                'pole1': JointMap(poles[0], DOWN, -1.0),
                'pole2': JointMap(poles[1], DOWN, -1.0)}
    raise ConfigError(f'engine mujoco: no MuJoCo model of {problem.model!r} (problem '
                      f'{problem.name}); it has acrobot and pdip')


def _link(name: str, joint: str, mass: float, com: float, inertia: float, length: float,
          inner: str = '', pos: str = '0 0 0') -> str:
    """A body hanging along -z from a hinge about +y (MJCF zero: hanging down)."""
    return (f'<body name="{name}" pos="{pos}">'
            f'<joint name="{joint}" type="hinge" axis="0 1 0"/>'
            f'<inertial pos="0 0 {-com!r}" mass="{mass!r}" '
            f'diaginertia="{inertia!r} {inertia!r} {inertia * 1e-6!r}"/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 {-length!r}" size="0.02"/>'
            f'{inner}</body>')


def mjcf(problem: Problem, physics: dict | None = None) -> str:
    """The MJCF document of ``problem``'s model (see the module table), with ``physics`` in
    place of the problem's own when given (a plant whose masses and lengths are off).  The
    single-pole cart stays one pole: of mass m1 + m2 and half-length (l1 + l2) / 2."""
    ph = problem.physics if physics is None else physics
    g = ph['g']
    if problem.model == 'acrobot':
        l1, l2 = ph['l1'], 2.0 * ph['lc2']
        link2 = _link('link2', 'elbow', ph['m2'], ph['lc2'], ph['I2'], l2,
                      pos=f'0 0 {-l1!r}')
        bodies = _link('link1', 'shoulder', ph['m1'], ph['lc1'], ph['I1'], l1, link2)
        actuator = 'elbow'
    else:
        mapping(problem)
        poles = ([('hinge', ph['m1'] + ph['m2'], (ph['l1'] + ph['l2']) / 2.0)]
                 if _single(problem) else
                 [('hinge1', ph['m1'], ph['l1']), ('hinge2', ph['m2'], ph['l2'])])
        inner = ''.join(_link(f'pole_{j}', j, m, half, m * half * half / 3.0, 2.0 * half)
                        for j, m, half in poles)
        x_max = ph['x_max']
        bodies = (f'<body name="cart"><joint name="slider" type="slide" axis="1 0 0" '
                  f'limited="true" range="{-x_max!r} {x_max!r}"/>'
                  f'<inertial pos="0 0 0" mass="{ph["m0"]!r}" diaginertia="1e-3 1e-3 1e-3"/>'
                  f'<geom type="box" size="0.1 0.05 0.05"/>{inner}</body>')
        actuator = 'slider'
    return (f'<mujoco model="{problem.name}">'
            f'<option timestep="{problem.dt!r}" integrator="RK4" gravity="0 0 {-g!r}"/>'
            '<default><geom contype="0" conaffinity="0"/></default>'
            f'<worldbody>{bodies}</worldbody>'
            f'<actuator><motor name="{actuator}_motor" joint="{actuator}" gear="1"/>'
            '</actuator></mujoco>')


class MujocoPlant:
    """A problem's robot simulated by MuJoCo (module docstring)."""

    def __init__(self, problem: Problem) -> None:
        import mujoco      # imported here: the kernel engine does not need it
        self._mujoco = mujoco
        self.problem = problem
        self.map = mapping(problem)
        self._build(problem.params())
        m = self.model
        self.joint_names = tuple(m.joint(k).name for k in range(m.njnt))
        self.actuator_joints = tuple(m.joint(m.actuator_trnid[k, 0]).name
                                     for k in range(m.nu))
        index = {name: k for k, name in enumerate(self.joint_names)}
        # per problem coordinate: (robot joint index, offset, direction, angle, velocity)
        self._coords = [(index[joint], off, sign, angle, vel)
                        for joint, off, sign, angle, vel in coordinates(problem)]
        self._reward_of = model_module(problem.model).mdp_step
        self._limit = problem.physics.get('x_max', math.inf)
        self.substeps = problem.substeps
        self.contact = False                  # the last step touched the joint limit

    def _build(self, p: np.ndarray) -> None:
        """The MuJoCo model of the packed physics ``p`` ([dt, substeps, *PARAMS])."""
        names = model_module(self.problem.model).PARAMS
        self.params = np.array(p, dtype=np.float64)
        self.xml = mjcf(self.problem, {n: float(v) for n, v in zip(names, self.params[2:])})
        self.model = self._mujoco.MjModel.from_xml_string(self.xml)
        self.data = self._mujoco.MjData(self.model)
        self._p0 = self.params.copy()
        self._p0[1] = 0.0                     # substeps = 0: the kernel's reward only

    def set_physics(self, p: np.ndarray) -> None:
        """Rebuild the robot with the packed physics ``p`` when they differ from its own (a
        disturbance's model error: masses and lengths drawn per episode); the same joints
        and actuators.  Call ``reset`` after it."""
        if not np.array_equal(p, self.params):
            self._build(p)

    def place(self, s: np.ndarray, before: np.ndarray | None = None) -> None:
        """Write into the robot every coordinate of the problem state ``s`` that differs from
        ``before``, the problem state the robot was last put in or reported (a push on the
        problem's state reaches the robot this way; nothing else is written); every
        coordinate when ``before`` is None."""
        for d, (j, off, sign, angle, vel) in enumerate(self._coords):
            if before is not None and s[d] == before[d]:
                continue
            if vel:
                self.data.qvel[j] = s[d] / sign
            else:
                q = (s[d] - off) / sign
                self.data.qpos[j] = math.remainder(q, TWO_PI) if angle else q

    def seen_joints(self, seen: np.ndarray, state: np.ndarray) -> tuple:
        """The robot's (positions, velocities) as a sensor reports them when the problem
        state ``state`` is seen as ``seen`` (the difference, sensor noise, added to each
        joint in its own convention; none: the joints themselves, bit for bit)."""
        q, v = self.data.qpos.copy(), self.data.qvel.copy()
        for d, (j, off, sign, angle, vel) in enumerate(self._coords):
            diff = seen[d] - state[d]
            if diff == 0.0:
                continue
            diff = math.remainder(diff, TWO_PI) if angle else diff
            if vel:
                v[j] = self.data.qvel[j] + diff / sign
            else:
                q[j] = self.data.qpos[j] + diff / sign
        return q, v

    @property
    def positions(self) -> np.ndarray:
        """The robot's joint positions (MuJoCo's qpos), in ``joint_names`` order."""
        return self.data.qpos

    @property
    def velocities(self) -> np.ndarray:
        """The robot's joint velocities (MuJoCo's qvel)."""
        return self.data.qvel

    def reset(self, s: np.ndarray) -> None:
        """Put the robot in the problem state ``s`` (at rest where ``s`` says so)."""
        self._mujoco.mj_resetData(self.model, self.data)
        self.place(s)
        self._mujoco.mj_forward(self.model, self.data)
        self.contact = False

    def step(self, effort: np.ndarray | float) -> None:
        """Hold the actuators' ``effort`` (robot convention) for one MDP step."""
        self.data.ctrl[:] = effort
        contact = False
        for _ in range(self.substeps):
            self._mujoco.mj_step(self.model, self.data)
            contact |= bool(np.any(np.abs(self.data.qpos[:1]) >= self._limit))
        self.contact = contact

    def problem_state(self, out: np.ndarray | None = None) -> np.ndarray:
        """The problem's state of the robot (angles wrapped to [0, 2pi))."""
        s = np.empty(self.problem.dim) if out is None else out
        q, v = self.data.qpos, self.data.qvel
        for d, (j, off, sign, angle, vel) in enumerate(self._coords):
            x = sign * v[j] if vel else off + sign * q[j]
            s[d] = x % TWO_PI if angle else x
        return s

    def problem_effort(self, value: float) -> float:
        """The robot effort of the problem's action ``value`` on its actuator joint."""
        return value * self.map[self.problem.actuator_joint].direction

    def reward(self, s: np.ndarray) -> float:
        """The problem's reward of the state ``s`` after a step (rail penalty on contact)."""
        r = self._reward_of(s.copy(), 0.0, self._p0)
        if self.contact and 'rail_penalty' in self.problem.physics:
            r += self.problem.physics['rail_penalty']
        return float(r)
