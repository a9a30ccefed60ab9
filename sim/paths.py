"""The scripted demonstrators' moves: minimum-jerk progress, waypoints through a list of phases (each phase a
minimum-jerk move of its drawn steps, or of more where a robot's limits need them: sim.controller.min_jerk_steps), a
demonstrator's plan handed out a step at a time and replanned (`Plan`), and an episode driven by one (`rollout`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cnep.sim import scene as S
from cnep.sim.controller import min_jerk_steps
from cnep.sim.robot import TELEPORT, RobotSettings


def yaw_quaternion(yaw_deg: float) -> np.ndarray:
    """The quaternion xyzw (4,) of a turn by `yaw_deg` degrees about z."""
    half = math.radians(yaw_deg) / 2
    return np.array([0.0, 0.0, math.sin(half), math.cos(half)])


def minimum_jerk(steps: int) -> np.ndarray:
    """The progress (steps,) from 0 to 1 of a minimum-jerk move at its steps 1 to `steps` (the last is 1)."""
    tau = np.arange(1, steps + 1) / steps
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5


def through(
    phases: list[tuple[tuple, float, float]],
    steps: tuple[int, ...],
    xyz: np.ndarray,
    yaw: float,
    robot: RobotSettings = TELEPORT,
) -> np.ndarray:
    """The waypoints (n, 8): xyz (m), quaternion xyzw, gripper, from `xyz` (m) and `yaw` (degrees) through `phases`,
    each where it ends (xyz, m), the yaw at its end (degrees) and the gripper command during it; each phase a
    minimum-jerk move of its `steps`, or of more where `robot`'s limits need them."""
    rows = []
    for (end, end_yaw, grip), drawn in zip(phases, steps):
        distance = float(np.linalg.norm(np.asarray(end) - xyz))
        n = max(drawn, min_jerk_steps(distance, math.radians(abs(end_yaw - yaw)), robot, S.CONTROL_PERIOD_S))
        for progress in minimum_jerk(n):
            point = xyz + progress * (np.asarray(end) - xyz)
            rows.append([*point, *yaw_quaternion(yaw + progress * (end_yaw - yaw)), grip])
        xyz, yaw = np.asarray(end, np.float64), end_yaw
    return np.asarray(rows)


class Plan:
    """A scripted demonstrator's waypoints (n, 8), handed out one a control step (`next`; the last one held once they
    run out), what is left replaced when it plans anew (`replan`)."""

    def __init__(self, waypoints: np.ndarray) -> None:
        self.waypoints, self.given = np.asarray(waypoints, np.float64), 0

    def next(self) -> np.ndarray:
        """The next waypoint (8,) float32."""
        if self.given == len(self.waypoints):
            self.waypoints = np.concatenate([self.waypoints, self.waypoints[-1:]])
        self.given += 1
        return self.waypoints[self.given - 1].astype(np.float32)

    def action(self, info: dict) -> np.ndarray:
        """The next waypoint (8,) float32, whatever the episode's `info`: the plan as an open-loop demonstrator."""
        return self.next()

    def last(self) -> np.ndarray | None:
        """The last waypoint handed out (8,), or None before the first."""
        return self.waypoints[self.given - 1].copy() if self.given else None

    def replan(self, waypoints: np.ndarray) -> None:
        """`waypoints` (m, 8) in place of those not handed out yet."""
        self.waypoints = np.concatenate([self.waypoints[: self.given], waypoints])


def rollout(env, act: Callable[[dict], np.ndarray], info: dict, seen: list[dict] | None = None) -> tuple[dict, int]:
    """Step `env` (just reset, its reset's `info`) with `act(info)`'s actions until the episode ends (terminated, or
    truncated at its step limit): the last info and the steps taken; each step's observation appended to `seen`
    where one is given."""
    steps, ended = 0, False
    while not ended:
        observation, _, terminated, truncated, info = env.step(act(info))
        steps, ended = steps + 1, terminated or truncated
        if seen is not None:
            seen.append(observation)
    return info, steps
