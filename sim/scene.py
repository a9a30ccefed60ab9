"""The obstacle task's tabletop: every size, position and margin as a named constant, and its MJCF.

Frame: the table's top is z = 0; the gripper travels from a start near (0, START_Y) to the goal (0, GOAL_Y),
past the box at the origin, at EE_HEIGHT above the table. Facing the goal (+y), left is -x and right is +x.
Units: metres, seconds, kilograms.
"""

from __future__ import annotations

# The table and the box to pass.
TABLE_HALF = (0.45, 0.45, 0.02)  # half sizes (m) of the table top, whose top face is z = 0
BOX_HALF = (0.05, 0.05, 0.06)  # half sizes (m) of the box, resting on the table at the origin
BOX_MASS = 0.5  # kg: a gripper that hits it pushes it
# The gripper: a palm and two fingers sliding apart along x.
EE_HEIGHT = 0.09  # m above the table: the palm's centre (the end effector's position)
PALM_HALF = (0.03, 0.015, 0.01)
FINGER_HALF = (0.006, 0.01, 0.03)  # each finger hangs below the palm: its bottom is 0.02 m above the table
FINGER_OPEN = 0.03  # m: each finger's travel from closed (the gripper value: 0 closed, FINGER_OPEN open)
GRIPPER_HALF_WIDTH = FINGER_OPEN + 2 * FINGER_HALF[0]  # m: the open gripper's half width along x
# The task: a start drawn around (0, START_Y), within START_JITTER on each axis; the fixed goal.
START_JITTER = 0.03  # m
MAX_STEPS = 60  # control steps of an episode (6 s): demonstrations take DEMO_STEPS
GOAL_TOLERANCE = 0.03  # m: an episode ends when the end effector comes this close to the goal (xy)
START_Y, GOAL_Y = -0.26, 0.26  # m: the start's and the goal's y
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
# The controller: the mocap target moves to each waypoint; the gripper body follows through a soft weld.
STATE_RESOLUTION = 1e-4  # the state as a robot reports it: m for positions and the gripper, and the quaternion's
CONTROL_PERIOD_S = 0.1  # s between two actions (10 Hz)
TIMESTEP_S = 0.005  # s: the physics step (20 per control period)
WELD_SOLREF = (0.02, 1.0)  # the weld's time constant (s) and damping ratio
FINGER_KP = 200.0  # N/m: the finger actuators' gain
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
GRIPPER_RGBA = (0.3, 0.3, 0.35, 1)
TABLE_RGBA = (0.75, 0.7, 0.6, 1)

# Names in the model.
GRIPPER_BODY, MOCAP_BODY, BOX_BODY = "gripper", "target", "box"
FINGER_JOINTS = ("finger_left", "finger_right")
BOX_GEOM, CUE_GEOM, TABLE_GEOM = "box", "cue", "table"


def v(values) -> str:
    """Numbers as the MJCF writes them: space-separated, in their shortest form."""
    return " ".join(f"{v:g}" for v in values)


def gripper_xml(finger_open: float = FINGER_OPEN) -> str:
    """The gripper's MJCF: the mocap target and a free body (palm and two fingers sliding apart along x, each by up
    to `finger_open` m) welded softly to it, both at the start; the `<equality>` and `<actuator>` blocks follow with
    gripper_constraints_xml."""
    fh, ph = FINGER_HALF, PALM_HALF
    fingers = "".join(
        f'<body name="{name}_body" pos="{sign * fh[0]:g} 0 {-(ph[2] + fh[2]):g}">'
        f'<joint name="{name}" type="slide" axis="{sign} 0 0" range="0 {finger_open:g}" damping="5"/>'
        f'<geom name="{name}_geom" type="box" size="{v(fh)}" mass="0.02" rgba="{v(GRIPPER_RGBA)}"/></body>'
        for name, sign in zip(FINGER_JOINTS, (-1, 1))
    )
    return f"""<body name="{MOCAP_BODY}" mocap="true" pos="0 {START_Y:g} {EE_HEIGHT:g}"/>
    <body name="{GRIPPER_BODY}" pos="0 {START_Y:g} {EE_HEIGHT:g}" gravcomp="1">
      <freejoint/>
      <geom name="palm" type="box" size="{v(ph)}" mass="0.2" rgba="{v(GRIPPER_RGBA)}"/>
      {fingers}
    </body>"""


def gripper_constraints_xml(finger_open: float = FINGER_OPEN) -> str:
    """The weld of the gripper to the mocap target and the fingers' position actuators (range 0 to `finger_open`)."""
    actuators = "".join(
        f'<position name="{name}" joint="{name}" kp="{FINGER_KP:g}" ctrlrange="0 {finger_open:g}"/>'
        for name in FINGER_JOINTS
    )
    return f"""<equality>
    <weld body1="{MOCAP_BODY}" body2="{GRIPPER_BODY}" solref="{v(WELD_SOLREF)}"/>
  </equality>
  <actuator>{actuators}</actuator>"""


def visual_xml(width: int = IMAGE_WIDTH, height: int = IMAGE_HEIGHT) -> str:
    """The render settings: an offscreen buffer of the frame's size, shadows off, a soft headlight."""
    return f"""<visual>
    <global offwidth="{width}" offheight="{height}"/>
    <quality shadowsize="0"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.5 0.5 0.5"/>
  </visual>"""


def scene_xml() -> str:
    """The MJCF of the tabletop: table, box (free), goal marker, cue tile (hidden until placed), gripper (a free
    body welded to the mocap target), the fixed camera; shadows off and an offscreen buffer of the frame's size."""
    return f"""<mujoco model="cnep-obstacle">
  <option timestep="{TIMESTEP_S:g}"/>
  {visual_xml()}
  <worldbody>
    <geom name="{TABLE_GEOM}" type="box" pos="0 0 {-TABLE_HALF[2]:g}" size="{v(TABLE_HALF)}" rgba="{v(TABLE_RGBA)}"/>
    <geom name="goal" type="cylinder" pos="{v(GOAL_XY)} 0.001" size="{GOAL_RADIUS:g} 0.001" rgba="{v(GOAL_RGBA)}"
      contype="0" conaffinity="0"/>
    <geom name="{CUE_GEOM}" type="box" pos="0 0 -0.5" size="{CUE_HALF:g} {CUE_HALF:g} 0.001" rgba="{v(CUE_RGBA)}"
      contype="0" conaffinity="0"/>
    <camera name="{CAMERA}" pos="{v(CAMERA_POS)}" xyaxes="{v(CAMERA_XYAXES)}" fovy="{CAMERA_FOVY:g}"/>
    <body name="{BOX_BODY}" pos="0 0 {BOX_HALF[2]:g}">
      <freejoint/>
      <geom name="{BOX_GEOM}" type="box" size="{v(BOX_HALF)}" mass="{BOX_MASS:g}" rgba="{v(BOX_RGBA)}"/>
    </body>
    {gripper_xml()}
  </worldbody>
  {gripper_constraints_xml()}
</mujoco>
"""
