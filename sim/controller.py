"""The end effector's target following the waypoints within a robot's Cartesian limits (sim.robot.RobotSettings).

As a robot's trajectory follower streams waypoints, the reference moves from the last waypoint to the next over the
control period at constant velocity (interpolated linearly, the orientation along the shorter turn). Each physics
step the target's velocity moves towards a desired velocity by at most the acceleration limit times the step, and the
target moves by it. The desired velocity is the reference's own (fed forward) plus a closing velocity towards the
reference, as fast as lets the target still stop there within the acceleration limit (sqrt(2 a d) at a distance d)
and no faster than the distance over the tracking time near it; the whole within the speed limit. The orientation
follows the same rule on its rotation vector (world frame) within the angular limits. So a waypoint stream the limits
allow is tracked without lag, and a jump is crossed at the arm's speed, braking before the waypoint.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from cnep.sim.robot import RobotSettings

SETTLED = 1e-9  # rad: an orientation this close to the reference's, turning this little a step, has settled there
PLAN_SHARE = 0.8  # a scripted demonstrator plans its moves within this share of the robot's limits
# A minimum-jerk move over a distance D in a time T peaks at 1.875 D / T in speed and 10 / sqrt(3) D / T² in
# acceleration.
MIN_JERK_SPEED, MIN_JERK_ACCELERATION = 1.875, 10 / np.sqrt(3)


class Follower:
    """The target's pose (position (3,) m, quaternion wxyz (4,)) and velocities, advanced one physics step of `dt` s
    at a time towards the reference within `limits`' speeds and accelerations; `period_s` is the control period (the
    time between two waypoints)."""

    def __init__(self, limits: RobotSettings, dt: float, period_s: float) -> None:
        if limits.max_speed is None:
            raise ValueError("a Follower needs a robot with a speed limit (RobotSettings.max_speed)")
        self.limits, self.dt, self.period_s = limits, dt, period_s
        self.reset(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))

    def reset(self, position: np.ndarray, quat: np.ndarray) -> None:
        """At rest at `position` (3,) m with orientation `quat` (4,) wxyz, which is also the waypoint."""
        self.position, self.velocity = np.array(position, np.float64), np.zeros(3)
        self.quat, self.angular = _unit(np.array(quat, np.float64)), np.zeros(3)
        self._from, self._move = self.position.copy(), np.zeros(3)
        self._from_quat, self._turn = self.quat.copy(), np.zeros(3)
        self._elapsed, self._turning = self.period_s, False

    def aim(self, position: np.ndarray, quat: np.ndarray) -> None:
        """The next waypoint, to be reached in one control period: `position` (3,) m and `quat` (4,) wxyz."""
        self._from, self._from_quat = self._reference()
        self._move = np.asarray(position, np.float64) - self._from
        self._turn = rotation(_unit(np.asarray(quat, np.float64)), self._from_quat)
        self._turning = self._turning or _norm(self._turn) > SETTLED
        self._elapsed = 0.0

    def step(self) -> None:
        """Advance the target one physics step towards the reference."""
        lim, dt = self.limits, self.dt
        moving = self._elapsed < self.period_s - 1e-12
        self._elapsed = min(self._elapsed + dt, self.period_s)
        reference, reference_quat = self._reference()
        feed = self._move / self.period_s if moving else 0.0
        desired = _desired(reference - self.position, feed, lim.max_speed, lim.max_acceleration, lim.tracking_s)
        self.velocity = _towards(self.velocity, desired, lim.max_acceleration * dt)
        self.position = self.position + self.velocity * dt
        if not self._turning:  # the orientation at the reference's, still: nothing to turn
            return
        error = rotation(reference_quat, self.quat)
        feed = self._turn / self.period_s if moving else 0.0
        desired = _desired(error, feed, lim.max_angular_speed, lim.max_angular_acceleration, lim.tracking_s)
        self.angular = _towards(self.angular, desired, lim.max_angular_acceleration * dt)
        self.quat = turned(self.quat, self.angular * dt)
        if _norm(self._turn) < SETTLED and _norm(error) < SETTLED and _norm(self.angular) * dt < SETTLED:
            self.quat, self.angular, self._turning = reference_quat, np.zeros(3), False

    def _reference(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the reference stands now: position (3,) m and quaternion wxyz (4,)."""
        share = self._elapsed / self.period_s
        quat = turned(self._from_quat, share * self._turn) if self._turning else self._from_quat
        return self._from + share * self._move, quat


def min_jerk_steps(distance: float, turn: float, limits: RobotSettings, period_s: float) -> int:
    """The fewest control periods of `period_s` s a minimum-jerk move over `distance` m while turning `turn` rad takes
    within PLAN_SHARE of `limits`' speeds and accelerations (1 without a speed limit)."""
    if limits.max_speed is None:
        return 1
    seconds = max(
        MIN_JERK_SPEED * distance / (PLAN_SHARE * limits.max_speed),
        np.sqrt(MIN_JERK_ACCELERATION * distance / (PLAN_SHARE * limits.max_acceleration)),
        MIN_JERK_SPEED * turn / (PLAN_SHARE * limits.max_angular_speed),
        np.sqrt(MIN_JERK_ACCELERATION * turn / (PLAN_SHARE * limits.max_angular_acceleration)),
    )
    return max(1, int(np.ceil(seconds / period_s - 1e-9)))


def rotation(to: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The rotation vector (3,) (axis times angle, rad, world frame, the shorter way) that turns orientation `start`
    into `to` (quaternions wxyz)."""
    difference, inverse = np.empty(4), np.empty(4)
    mujoco.mju_negQuat(inverse, start)
    mujoco.mju_mulQuat(difference, to, inverse)
    if difference[0] < 0:  # q and -q are one orientation: take the turn of at most half a revolution
        difference = -difference
    vector = np.empty(3)
    mujoco.mju_quat2Vel(vector, difference, 1.0)
    return vector


def turned(quat: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Orientation `quat` (4,) wxyz turned by the rotation vector `vector` (3,) (axis times angle, rad, world frame),
    a new unit quaternion."""
    turn, result = np.array([1.0, 0.0, 0.0, 0.0]), np.empty(4)
    mujoco.mju_quatIntegrate(turn, np.asarray(vector, np.float64), 1.0)
    mujoco.mju_mulQuat(result, turn, quat)
    return _unit(result)


def _desired(error: np.ndarray, feed: np.ndarray, speed: float, acceleration: float, tracking_s: float) -> np.ndarray:
    """The velocity (3,) wanted: `feed` plus the closing velocity along `error` (module docstring), within `speed`."""
    distance = _norm(error)
    closing = min(math.sqrt(2 * acceleration * distance), distance / tracking_s)
    wanted = feed + (error / distance * closing if distance > 0 else 0.0)
    return _clip_norm(wanted, speed)


def _towards(velocity: np.ndarray, desired: np.ndarray, most: float) -> np.ndarray:
    """`velocity` changed towards `desired` by at most `most` (the norm of the change)."""
    return velocity + _clip_norm(desired - velocity, most)


def _clip_norm(vector: np.ndarray, most: float) -> np.ndarray:
    norm = _norm(vector)
    return vector * (most / norm) if norm > most else vector


def _norm(vector: np.ndarray) -> float:
    return math.sqrt(float(vector.dot(vector)))  # np.linalg.norm's checks cost more than the sum, 20 times a step


def _unit(quat: np.ndarray) -> np.ndarray:
    return quat / _norm(quat)
