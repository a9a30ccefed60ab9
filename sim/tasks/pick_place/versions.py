"""The pick-and-place environment's versions (`cnep/PickPlace-v0`, `cnep/PickPlace-v1`): the robot, the scenes'
randomisation, the bar and the gripper's grip, when the `changed` scene changes and an episode's length.

v0 is the scene module's numbers: the gripper's target jumps to each waypoint, the state and frames are exact, the
bar lies within 2 cm and 5 degrees of its pose, the grip holds 28 x the bar's weight, and the cup moves at a drawn
step (8-24, before the grasp closes). v1 is a robot's: the arm's limits and sensing (sim.robot.ARM), the start within
10 cm, the bar within 5 cm and 20 degrees, a real gripper's force on a bar of real weight (`grip_margin`: about 4 x),
and the cup moves during the carry, once the bar is lifted and the gripper has covered a drawn share of the way to
the place it heads for.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnep.sim import scene as S
from cnep.sim.robot import ARM, TELEPORT, RobotSettings
from cnep.sim.tasks.pick_place import scene as P

GRAVITY = 9.81  # m/s²
DEFAULT_FRICTION = 1.0  # MuJoCo's sliding friction of a geom that sets none (the fingers' in v0)
AT_STEP, IN_CARRY = "step", "carry"  # when the changed scene changes: at a drawn step, or during the carry


@dataclass(frozen=True)
class PickPlaceVersion:
    """One version of the environment.

    robot: what moves and senses (sim.robot); start: the gripper's (x, y, z) m, drawn within start_jitter on x and y;
    object_jitter: m on x and y around P.OBJECT_XY; yaw_jitter_deg: the bar's yaw around its orientation's (degrees);
    object_mass: kg; grip: a real gripper's (sim.scene.Grip: its pads' friction, the bar's too, and its force), or
    None: the idealised gripper (position actuators of S.FINGER_KP unlimited, the fingers MuJoCo's default friction,
    the bar P.OBJECT_FRICTION; a contact takes the larger); change: AT_STEP (the cup moves at a step drawn from
    P.CHANGE_STEPS) or IN_CARRY (once the bar is lifted and the gripper has covered a share drawn from `change_share`
    of the way from where it lifted the bar to the place it heads for); max_steps: control steps an episode;
    pace_per_phase: the scripted demonstrator draws each phase's pace apart, else one for its whole motion.
    """

    robot: RobotSettings
    start: tuple[float, float, float]
    start_jitter: float
    object_jitter: float
    yaw_jitter_deg: float
    object_mass: float
    grip: S.Grip | None
    change: str
    change_share: tuple[float, float]
    max_steps: int
    pace_per_phase: bool


V0 = PickPlaceVersion(
    robot=TELEPORT,
    start=P.START,
    start_jitter=P.START_JITTER,
    object_jitter=P.OBJECT_JITTER,
    yaw_jitter_deg=P.YAW_JITTER_DEG,
    object_mass=P.OBJECT_MASS,
    grip=None,
    change=AT_STEP,
    change_share=(0.0, 0.0),
    max_steps=P.MAX_STEPS,
    pace_per_phase=False,
)
V1 = PickPlaceVersion(
    robot=ARM,
    start=(0.0, -0.24, 0.2),  # nearer the bar than v0's, so that the camera sees a start 10 cm off
    start_jitter=0.10,
    object_jitter=0.05,
    yaw_jitter_deg=20.0,
    object_mass=0.25,  # kg: a solid plastic bar of the bar's size (245 cm³ at about 1 g/cm³)
    # Rubber-tipped fingers on smooth plastic; 10 N: a light part's setting of a small electric gripper (OnRobot's RG2
    # grips with 3-40 N).
    grip=S.Grip(friction=0.5, force=10.0),
    change=IN_CARRY,
    change_share=(0.2, 0.5),
    max_steps=120,
    pace_per_phase=True,
)
VERSIONS = (V0, V1)


def grip_margin(version: PickPlaceVersion) -> float:
    """How many times the bar's weight the grip's friction holds: both fingers' friction (2 mu F, F the squeeze: the
    force limit, or the position actuator's pull when closed on the bar) over m g."""
    if version.grip is None:
        friction, squeeze = max(P.OBJECT_FRICTION, DEFAULT_FRICTION), S.FINGER_KP * P.OBJECT_HALF[0]
    else:
        friction, squeeze = version.grip.friction, version.grip.force
    return 2 * friction * squeeze / (version.object_mass * GRAVITY)


def version_of(number: int) -> PickPlaceVersion:
    """The version `number` (0 or 1)."""
    if not 0 <= number < len(VERSIONS):
        raise ValueError(f"the pick-and-place environment has versions 0 to {len(VERSIONS) - 1}, got {number}")
    return VERSIONS[number]
