"""The simulator node's MuJoCo engine (``engine:=mujoco``): the plant behind the topics.

``MujocoEngine(problem)`` wraps ``sim_nodes.mujoco_plant.MujocoPlant`` with what the node
needs: ``mdp_step(s, action, p)`` with the kernels' signature (the action in the problem's
convention; ``s`` becomes the problem state of the robot, for reward, goal and markers),
``reset(s)``, the robot's ``sensor_msgs/JointState`` (``new_msg``/``fill``: MuJoCo's joint
names, positions, velocities and efforts in its own convention) and ``action(data)``, the
problem's action of an effort command (one value per actuator, robot convention:
``std_msgs/Float64MultiArray``, and ``command`` / ``command_stamped`` on ``actuator_joint``;
``MessageError`` for a wrong length).
"""
from __future__ import annotations

import array
from typing import Sequence

import numpy as np
from sensor_msgs.msg import JointState

from sim_nodes.mujoco_plant import MujocoPlant
from sim_nodes.problem import Problem
from sim_nodes.ros.common import MessageError, set_stamp

ENGINES = ('kernel', 'mujoco')


class MujocoEngine:
    """A problem's MuJoCo robot as the simulator node steps and publishes it."""

    def __init__(self, problem: Problem) -> None:
        self.plant = plant = MujocoPlant(problem)
        self._state = plant.problem_state()
        self.frame_id = str(problem.ros.get('frame_id', problem.name))
        self.actuator_joint = plant.actuator_joints[0]
        self._actuated = plant.joint_names.index(self.actuator_joint)
        self._direction = plant.problem_effort(1.0)

    def reset(self, s: np.ndarray, p: np.ndarray | None = None) -> None:
        """Start an episode at the problem state ``s``, the robot rebuilt with the packed
        physics ``p`` when given (the episode's model error)."""
        if p is not None:
            self.plant.set_physics(p)
        self.plant.reset(s)
        self._state = s.copy()        # the problem state the robot was put in or reported

    def mdp_step(self, s: np.ndarray, action: float, p: np.ndarray) -> float:
        """Hold ``action`` (the problem's convention) for one MDP step from ``s`` (any
        coordinate of it that is not the robot's, a push, is written into the robot first);
        ``s`` gets the problem state of the robot; the step's reward."""
        self.plant.place(s, self._state)
        self.plant.step(self._direction * action)
        self.plant.problem_state(s)
        self._state = s.copy()
        return self.plant.reward(s)

    def action(self, data: Sequence[float]) -> float:
        """The problem's action of an effort command (one value per actuator)."""
        n = self.plant.model.nu
        if len(data) != n:
            raise MessageError(f'effort command with {len(data)} values: the robot has {n} '
                               f'actuator(s) ({", ".join(self.plant.actuator_joints)})')
        return float(data[0]) * self._direction

    def new_msg(self) -> JointState:
        msg = JointState()
        msg.name = list(self.plant.joint_names)
        msg.header.frame_id = self.frame_id
        return msg

    def fill(self, msg: JointState, s: np.ndarray, effort: float, stamp: int) -> JointState:
        """The robot's joints as seen (``s``: the problem state as its sensors see it, their
        noise added to the joints) and the applied ``effort`` (the problem's action, published
        in the robot's convention) at ``stamp`` [ns]."""
        eff = [0.0] * len(self.plant.joint_names)
        eff[self._actuated] = self._direction * effort
        set_stamp(msg.header, stamp)
        q, v = self.plant.seen_joints(s, self._state)
        msg.position = array.array('d', q)
        msg.velocity = array.array('d', v)
        msg.effort = array.array('d', eff)
        return msg
