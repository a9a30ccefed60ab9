"""The obstacle environment's versions (`cnep/Obstacle-v0` and `-v1`, `cnep/ObstacleCue-v0` and `-v1`): the robot,
where the start, the box and the goal lie, when the cue shows, and an episode's length.

v0 is the scene module's numbers: the gripper's target jumps to each waypoint, the state and frames are exact, the
start lies within 3 cm of its place, the box and the goal never move, and the cue shows from the start. v1 is a
robot's: the arm's limits and sensing (sim.robot.ARM), the start within 10 cm, the box within 5 cm and 20 degrees, the
goal within 5 cm, and the cue shows during the motion: once the gripper has moved a drawn distance towards the goal,
or at a step at the latest.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnep.sim.robot import ARM, TELEPORT, RobotSettings
from cnep.sim.tasks.obstacle import scene as O


@dataclass(frozen=True)
class ObstacleVersion:
    """One version of the environment.

    robot: what moves and senses (sim.robot); start, goal: (x, y) m, around which the start and the goal are drawn
    within start_jitter and goal_jitter (m, on x and y); box_jitter: m on x and y around the origin; box_yaw_deg: the
    box's yaw within this (degrees); cue_after: the cue variant's cue shows once the gripper has moved a distance drawn
    within these (m, along y towards the goal) or at step cue_latest_step, whichever comes first (None: it shows from
    the start); max_steps: control steps an episode; phases: the scripted demonstrator moves in phases around the box
    where it stands (demonstrator.ObstacleExpert), else along v0's bump past the origin (demonstration_path).
    """

    robot: RobotSettings
    start: tuple[float, float]
    start_jitter: float
    goal: tuple[float, float]
    goal_jitter: float
    box_jitter: float
    box_yaw_deg: float
    cue_after: tuple[float, float] | None
    cue_latest_step: int
    max_steps: int
    phases: bool


V0 = ObstacleVersion(
    robot=TELEPORT,
    start=(0.0, O.START_Y),
    start_jitter=O.START_JITTER,
    goal=O.GOAL_XY,
    goal_jitter=0.0,
    box_jitter=0.0,
    box_yaw_deg=0.0,
    cue_after=None,
    cue_latest_step=0,
    max_steps=O.MAX_STEPS,
    phases=False,
)
V1 = ObstacleVersion(
    robot=ARM,
    start=(0.0, -0.32),  # farther from the box than v0's, so that a start 10 cm nearer leaves room to turn aside
    start_jitter=0.10,
    goal=(0.0, 0.30),
    goal_jitter=0.05,
    box_jitter=0.05,
    box_yaw_deg=20.0,
    cue_after=(0.02, 0.06),
    cue_latest_step=12,
    max_steps=80,
    phases=True,
)
VERSIONS = (V0, V1)


def version_of(number: int) -> ObstacleVersion:
    """The version `number` (0 or 1)."""
    if not 0 <= number < len(VERSIONS):
        raise ValueError(f"the obstacle environment has versions 0 to {len(VERSIONS) - 1}, got {number}")
    return VERSIONS[number]
