"""The obstacle task's tabletop: every size, position and margin as a named constant, and its MJCF.

The gripper (sim.scene's) travels from a start near (0, START_Y) to the goal (0, GOAL_Y), past the box at the
origin, at EE_HEIGHT above the table. Facing the goal (+y), left is -x and right is +x. Units: metres, seconds,
kilograms.
"""

from __future__ import annotations

from cnep.sim import scene as S

# The box to pass.
BOX_HALF = (0.05, 0.05, 0.06)  # half sizes (m) of the box, resting on the table at the origin
BOX_MASS = 0.5  # kg: a gripper that hits it pushes it
EE_HEIGHT = 0.09  # m above the table: the palm's centre (the end effector's position); the fingers' bottoms 2 cm
# The task: a start drawn around (0, START_Y), within START_JITTER on each axis; the fixed goal.
START_JITTER = 0.03  # m
MAX_STEPS = 60  # control steps of an episode (6 s): demonstrations take DEMO_STEPS
GOAL_TOLERANCE = 0.03  # m: an episode ends when the end effector comes this close to the goal (xy)
START_Y, GOAL_Y = -0.26, 0.26  # m: the start's and the goal's y
SIDE_SIGN = {"left": -1.0, "right": 1.0}  # the sides to pass the box on: facing the goal (+y), left is -x
SIDES = tuple(SIDE_SIGN)
GOAL_XY = (0.0, GOAL_Y)
GOAL_RADIUS = 0.04  # m: the goal marker's radius
CUE_XY = (0.2, 0.13)  # m: the cue tile's |x| (on the side to pass, in the cue variant) and y (beyond the box)
CUE_HALF = 0.04  # m: the tile's half size
# The scripted demonstrator (sim.tasks.obstacle.demonstrator): per demonstration a side, a number of steps (its
# speed), the detour's lateral reach at the box and its shape (the exponent of the bump: < 1 flatter near the box),
# each drawn uniformly.
DEMO_STEPS = (34, 44)  # control steps from start to goal, inclusive range
DETOUR = (
    0.19,
    0.23,
)  # m: the detour's |x| at the box (the box's edge is at BOX_HALF[0], the gripper's GRIPPER_HALF_WIDTH)
DETOUR_SHAPE = (0.5, 1.0)  # the bump's exponent: x = detour * sin(pi * s) ** shape along the path's progress s
DETOUR_PEAK = (0.42, 0.58)  # the progress s at which the detour peaks
# The v1 demonstrator (a robot's: the box and the goal moved, a cue that shows during the motion) moves in phases, each
# a minimum-jerk move of its own drawn steps (or more, within the arm's limits): `approach` straight towards the box,
# stopping HOLD_BEFORE short of its centre, until the cue shows (the cue variant only); `out` to beside the box, DETOUR
# from its centre across and REACH before it; `past` to as far beyond it; `in` to the goal.
DETOUR_PHASES = {"approach": (10, 16), "out": (8, 14), "past": (5, 9), "in": (8, 14)}
REACH = (0.10, 0.13)  # m: along y from the box's centre (its corners reach 0.07 at 20 degrees, the palm 0.015)
HOLD_BEFORE = 0.18  # m: along y from the box's centre
# The camera: fixed, in front of the table, looking down at it; a real camera's 4:3 frames.
CAMERA = "front"
IMAGE_WIDTH, IMAGE_HEIGHT = 160, 120
CAMERA_POS = (0.0, -0.45, 0.75)  # m
CAMERA_XYAXES = (1, 0, 0, 0, 0.866, 0.5)  # its x and y axes in the world: looking 60 degrees down, towards +y
CAMERA_FOVY = 55.0  # degrees
# Colours (RGBA).
BOX_RGBA = (0.8, 0.3, 0.2, 1)
GOAL_RGBA = (0.1, 0.8, 0.2, 1)
CUE_RGBA = (0.1, 0.3, 0.9, 1)

# Names in the model.
BOX_BODY = "box"
BOX_GEOM, CUE_GEOM = "box", "cue"


def scene_xml() -> str:
    """The MJCF of the tabletop: table, box (free), goal marker, cue tile (hidden until placed), gripper (a free
    body welded to the mocap target), the fixed camera; shadows off and an offscreen buffer of the frame's size."""
    v = S.v
    return f"""<mujoco model="cnep-obstacle">
  <option timestep="{S.TIMESTEP_S:g}"/>
  {S.visual_xml(IMAGE_WIDTH, IMAGE_HEIGHT)}
  <worldbody>
    <geom name="{S.TABLE_GEOM}" type="box" pos="0 0 {-S.TABLE_HALF[2]:g}" size="{v(S.TABLE_HALF)}"
      rgba="{v(S.TABLE_RGBA)}"/>
    <geom name="goal" type="cylinder" pos="{v(GOAL_XY)} 0.001" size="{GOAL_RADIUS:g} 0.001" rgba="{v(GOAL_RGBA)}"
      contype="0" conaffinity="0"/>
    <geom name="{CUE_GEOM}" type="box" pos="0 0 -0.5" size="{CUE_HALF:g} {CUE_HALF:g} 0.001" rgba="{v(CUE_RGBA)}"
      contype="0" conaffinity="0"/>
    <camera name="{CAMERA}" pos="{v(CAMERA_POS)}" xyaxes="{v(CAMERA_XYAXES)}" fovy="{CAMERA_FOVY:g}"/>
    <body name="{BOX_BODY}" pos="0 0 {BOX_HALF[2]:g}">
      <freejoint/>
      <geom name="{BOX_GEOM}" type="box" size="{v(BOX_HALF)}" mass="{BOX_MASS:g}" rgba="{v(BOX_RGBA)}"/>
    </body>
    {S.gripper_xml()}
  </worldbody>
  {S.gripper_constraints_xml()}
</mujoco>
"""
