"""The scripted demonstrator of the obstacle task: start to goal past the box on one side, with natural variation.

A demonstration (`DemoDraw`, drawn by `draw_demonstration` from a generator) has a side, a number of steps (its
speed), the detour's lateral reach at the box and the shape of the bump (scene.DEMO_STEPS, DETOUR, DETOUR_SHAPE,
DETOUR_PEAK). Its path (`demonstration_path`) runs from the start to the goal with a minimum-jerk timing; the lateral
offset is a bump that reaches the detour at the peak's progress: x = start_x (1 - s) + sign * detour * bump(s).
`demonstrations` drives the environment with them (v1: with `ObstacleExpert`), as a robot records a demonstration.

In v1 (the box and the goal moved, a robot's limits, a cue that shows during the motion) the demonstrator moves in
phases, each of its own drawn pace (`DetourDraw`, `draw_detour`): out to beside the box, past it, in to the goal; in
the cue variant it first approaches and waits for the cue (`ObstacleExpert`, in closed loop).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from cnep.runtime import STATE_KEY
from cnep.sim import scene as S
from cnep.sim.paths import Plan, rollout, through
from cnep.sim.robot import RobotSettings
from cnep.sim.task import Demonstration, demonstration_seed, recorded
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.env import ObstacleEnv
from cnep.sim.tasks.obstacle.versions import version_of


@dataclass(frozen=True)
class DemoDraw:
    """One demonstration's choices: side ("left" / "right"), steps (control steps from start to goal), detour (m),
    shape (the bump's exponent), peak (the progress in (0, 1) where the detour is widest)."""

    side: str
    steps: int
    detour: float
    shape: float
    peak: float


def draw_demonstration(rng: np.random.Generator, side: str | None = None) -> DemoDraw:
    """A demonstration's choices drawn from `rng`; `side` None: left or right with equal chance."""
    side = side if side is not None else ("left", "right")[int(rng.integers(2))]
    lo, hi = O.DEMO_STEPS
    return DemoDraw(
        side=side,
        steps=int(rng.integers(lo, hi + 1)),
        detour=float(rng.uniform(*O.DETOUR)),
        shape=float(rng.uniform(*O.DETOUR_SHAPE)),
        peak=float(rng.uniform(*O.DETOUR_PEAK)),
    )


def demonstration_path(draw: DemoDraw, start: np.ndarray) -> np.ndarray:
    """The waypoints (draw.steps, 3) in m after `start` (x, y): waypoint k is where the end effector goes at step
    k + 1; the last is the goal."""
    tau = np.arange(1, draw.steps + 1) / draw.steps
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5  # minimum-jerk progress, 0 -> 1
    warped = np.where(s < draw.peak, 0.5 * s / draw.peak, 0.5 + 0.5 * (s - draw.peak) / (1 - draw.peak))
    bump = np.sin(np.pi * warped) ** draw.shape  # 0 at the ends, 1 at the peak
    x = start[0] * (1 - s) + O.GOAL_XY[0] * s + O.SIDE_SIGN[draw.side] * draw.detour * bump
    y = start[1] * (1 - s) + O.GOAL_XY[1] * s
    return np.stack([x, y, np.full_like(x, O.EE_HEIGHT)], axis=1)


def demonstrations(n: int, seed: int, cue: bool = False, version: int = 0) -> Iterator[Demonstration]:
    """`n` demonstrations drawn with `seed`, each driving the environment of `version` from its own reset: half pass
    left, half right, in a seeded order (in the cue variant the cue shows the side); clean when it reached the goal
    clear of the box. v0 follows its path (demonstration_path) to the end; v1 is the scripted demonstrator in closed
    loop (obstacle_expert: its phases' paces drawn apart, waiting for the cue in the cue variant) until the episode
    ends, the states and frames as the robot sensed them."""
    rng = np.random.default_rng(seed)
    sides = [O.SIDES[i % 2] for i in range(n)]
    rng.shuffle(sides)
    phases = version_of(version).phases
    env = ObstacleEnv(cue=cue, version=version, max_steps=None if phases else O.DEMO_STEPS[1] + 1)
    try:
        for i, side in enumerate(sides):
            observation, info = env.reset(seed=demonstration_seed(seed, i), options={"cue_side": side} if cue else None)
            steps = [observation]
            if phases:
                info, _ = rollout(env, obstacle_expert(env, rng, side).action, info, steps)
            else:
                info = _follow(env, demonstration_path(draw_demonstration(rng, side), info["start"]), steps)
            clean = bool(info["distance_to_goal"] < O.GOAL_TOLERANCE and not info["collision"])
            yield recorded(steps, env.image_key, side, clean)
    finally:
        env.close()


def _follow(env: ObstacleEnv, path: np.ndarray, steps: list[dict]) -> dict:
    """Step `env` through the waypoints `path` (n, 3) to its end, the orientation the one last observed (steps[-1],
    the reset's first), each observation appended to `steps`; the last step's info."""
    for waypoint in path:
        action = np.array([*waypoint, *steps[-1][STATE_KEY][3:7], S.FINGER_OPEN], dtype=np.float32)
        observation, _, _, _, info = env.step(action)
        steps.append(observation)
    return info


@dataclass(frozen=True)
class DetourDraw:
    """A v1 demonstration's choices: side ("left" / "right"), steps per phase (scene.DETOUR_PHASES' order), detour
    (m across from the box's centre to the end effector's path beside it), reach (m along y from the box's centre to
    where the path beside it begins and ends)."""

    side: str
    steps: tuple[int, ...]
    detour: float
    reach: float


def draw_detour(rng: np.random.Generator, side: str | None = None) -> DetourDraw:
    """A v1 demonstration's choices drawn from `rng`: each phase's steps apart; `side` None: left or right with
    equal chance."""
    side = side if side is not None else ("left", "right")[int(rng.integers(2))]
    return DetourDraw(
        side=side,
        steps=tuple(int(rng.integers(lo, hi + 1)) for lo, hi in O.DETOUR_PHASES.values()),
        detour=float(rng.uniform(*O.DETOUR)),
        reach=float(rng.uniform(*O.REACH)),
    )


class ObstacleExpert:
    """The v1 scripted demonstrator in closed loop, in the environment's `scene` (ObstacleEnv.scene: the start, the
    box, the goal) from the reset on, within `robot`'s limits. Where a cue is to show (`wait`), it approaches straight
    towards the box, stopping HOLD_BEFORE short of its centre, and once the cue shows turns aside on the cue's side,
    from its last waypoint on; else it passes on the drawn side from the start."""

    def __init__(self, draw: DetourDraw, scene: dict, robot: RobotSettings, wait: bool) -> None:
        self.draw, self.scene, self.robot, self.waiting = draw, scene, robot, wait
        self.start = np.array([*scene["start"], O.EE_HEIGHT])
        if wait:
            hold = (self.start[0], max(self.start[1], scene["box_xy"][1] - O.HOLD_BEFORE), O.EE_HEIGHT)
            self.plan = Plan(through([(hold, 0.0, S.FINGER_OPEN)], draw.steps[:1], self.start, 0.0, robot))
        else:
            self.plan = Plan(through(self._detour(draw.side), draw.steps[1:], self.start, 0.0, robot))

    def action(self, info: dict) -> np.ndarray:
        """The action (8,) float32 after `info` (the reset's, then each step's)."""
        if self.waiting and info["cue_step"] is not None:
            last = self.plan.last()
            here = self.start if last is None else last[:3]
            self.plan.replan(through(self._detour(info["cue_side"]), self.draw.steps[1:], here, 0.0, self.robot))
            self.waiting = False
        return self.plan.next()

    def _detour(self, side: str) -> list[tuple[tuple, float, float]]:
        """The phases out, past and in (sim.paths.through's) passing the box on `side`."""
        (box_x, box_y), (goal_x, goal_y) = self.scene["box_xy"], self.scene["goal_xy"]
        x = box_x + O.SIDE_SIGN[side] * self.draw.detour
        ends = [(x, box_y - self.draw.reach), (x, box_y + self.draw.reach), (goal_x, goal_y)]
        return [((*end, O.EE_HEIGHT), 0.0, S.FINGER_OPEN) for end in ends]


def obstacle_expert(env: ObstacleEnv, rng: np.random.Generator, side: str | None = None) -> ObstacleExpert | Plan:
    """The scripted demonstrator of `env` (an ObstacleEnv just reset), its choices drawn from `rng` (`side` None: the
    cue's in the cue variant, else drawn), with an `action(info)`: in v1 ObstacleExpert (draw_detour; within the
    robot's limits, waiting for the cue in the cue variant), else v0's path (draw_demonstration) as a Plan."""
    side = side if side is not None else env.cue_side
    if env.version.phases:
        return ObstacleExpert(draw_detour(rng, side), env.scene, env.version.robot, wait=env.cue)
    waypoints = demonstration_path(draw_demonstration(rng, side), env.scene["start"])
    pose = np.broadcast_to([0.0, 0.0, 0.0, 1.0, S.FINGER_OPEN], (len(waypoints), 5))
    return Plan(np.concatenate([waypoints, pose], axis=1))
