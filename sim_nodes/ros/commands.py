"""Commands that answer states: the stamped command message and the checks the
simulator applies to every command.

Two command inputs of the simulator (docs/ros_interface.md):

* ``command_stamped`` (``sensor_msgs/JointState``), what the policy node publishes:
  ``header.stamp`` = the stamp of the state it answers, ``name`` = [the actuator joint],
  ``effort`` = [torque / force], ``frame_id`` = ``ros.frame_id``.  In lockstep only a command
  answering the current state steps; any other (the answer to a state before a reset, a
  duplicate) is ignored and counted as late, so no stale command steps a new episode or
  starts one.  In realtime the latest command is held from the next tick on, even one that
  answers an older state (it is the freshest the policy has said); a state that no command
  answered before the next tick is counted as late (``count_unanswered``).
* ``command`` (``std_msgs/Float64``), for hand use (``ros2 topic pub``).  It carries no stamp:
  lockstep takes it as the answer to the current state, so a reset while one is in flight
  lets it step the new episode's first state (the race the stamped topic closes); realtime
  takes it as the current state's answer too.

Both: NaN / inf ignored, out-of-range values clamped to the actuator limit, each counted with
a throttled warning (``CommandCheck``).
"""
from __future__ import annotations

import array
import math
from typing import Any

from sensor_msgs.msg import JointState

from sim_nodes.problem import Problem
from sim_nodes.ros.common import THROTTLE_S, MessageError, set_stamp, stamp_ns


class StampedCommand:
    """The ``command_stamped`` message of a problem: ``fill`` (policy node), ``read`` (sim)."""

    def __init__(self, problem: Problem) -> None:
        self.joint = problem.actuator_joint
        self.msg = JointState()
        self.msg.name = [self.joint]
        self.msg.header.frame_id = str(problem.ros.get('frame_id', problem.name))

    def fill(self, value: float, stamp: int) -> JointState:
        """The reused message carrying ``value`` as the answer to the state stamped ``stamp``."""
        set_stamp(self.msg.header, stamp)
        self.msg.effort = array.array('d', (value,))
        return self.msg

    def read(self, msg: JointState) -> tuple[int, float]:
        """(stamp [ns] of the state answered, command value); ``MessageError`` when the
        actuator joint is missing or ``effort`` does not match ``name``."""
        names = list(msg.name)
        if len(msg.effort) != len(names):
            raise MessageError(f'stamped command has {len(names)} names but '
                               f'{len(msg.effort)} efforts')
        if self.joint not in names:
            raise MessageError(f'stamped command lacks joint {self.joint!r} '
                               f'(got {names})'[:200])
        return stamp_ns(msg), float(msg.effort[names.index(self.joint)])


class CommandCheck:
    """The simulator's checks of command values, with counters and throttled warnings."""

    def __init__(self, limit: float, logger: Any) -> None:
        self.limit = limit          # the actuator limit, max |action|
        self.ignored = 0            # non-finite or malformed commands
        self.clamped = 0            # out-of-range commands
        self.late = 0               # commands answering another (lockstep) / older state
        self._logger = logger

    def value(self, value: float) -> float | None:
        """The value to apply (clamped to the limit), or None to ignore it (non-finite)."""
        if not math.isfinite(value):
            self.reject(f'non-finite command {value}')
            return None
        if abs(value) > self.limit:
            self.clamped += 1
            self._logger.warning(f'command {value} clamped to the actuator limit {self.limit}',
                                 throttle_duration_sec=THROTTLE_S)
            return math.copysign(self.limit, value)
        return value

    def reject(self, why: str) -> None:
        """Count and report a command that is not applied."""
        self.ignored += 1
        self._logger.warning(f'ignoring {why}', throttle_duration_sec=THROTTLE_S)

    def count_unanswered(self, current: int) -> None:
        """Count and report (realtime) the state at ``current`` [ns] that no command
        answered before the next tick."""
        self.late += 1
        self._logger.warning(f'no command answered the state at {current * 1e-9:.3f} s '
                             f'within its tick ({self.late} late so far)',
                             throttle_duration_sec=THROTTLE_S)

    def count_late(self, answered: int, current: int) -> None:
        """Count and report (lockstep) an ignored command answering the state at
        ``answered`` [ns] when the current state is at ``current`` [ns]."""
        self.late += 1
        self._logger.warning(f'command for the state at {answered * 1e-9:.3f} s ignored: the '
                             f'current state is at {current * 1e-9:.3f} s ({self.late} late so '
                             'far)', throttle_duration_sec=THROTTLE_S)
