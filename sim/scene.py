"""What every task's tabletop shares: the table, the floating gripper and its controller, the control period, the
render settings, as named constants, and the gripper's MJCF.

Frame: the table's top is z = 0; facing +y, left is -x and right is +x. Units: metres, seconds, kilograms.
"""

from __future__ import annotations

from dataclasses import dataclass

TABLE_HALF = (0.45, 0.45, 0.02)  # half sizes (m) of the table top, whose top face is z = 0
# The gripper: a palm and two fingers sliding apart along x.
PALM_HALF = (0.03, 0.015, 0.01)
FINGER_HALF = (0.006, 0.01, 0.03)  # each finger hangs below the palm
FINGER_OPEN = 0.03  # m: each finger's travel from closed (the gripper value: 0 closed, FINGER_OPEN open)
GRIPPER_HALF_WIDTH = FINGER_OPEN + 2 * FINGER_HALF[0]  # m: the open gripper's half width along x
GRIPPER_HOME = (0.0, -0.26, 0.09)  # m: where the gripper and its target stand in the MJCF, until a reset places them
# The controller: the mocap target moves to each waypoint; the gripper body follows through a soft weld.
STATE_RESOLUTION = 1e-4  # the state as a robot reports it: m for positions and the gripper, and the quaternion's
CONTROL_PERIOD_S = 0.1  # s between two actions (10 Hz)
TIMESTEP_S = 0.005  # s: the physics step (20 per control period)
WELD_SOLREF = (0.02, 1.0)  # the weld's time constant (s) and damping ratio
FINGER_KP = 200.0  # N/m: the finger actuators' gain
FINGER_MASS = 0.02  # kg: each finger
# A real gripper (`Grip`): its fingers move together (one drive, as a parallel gripper's linkage), each pushing with at
# most its grip force, and they weigh what such fingers do (light ones let the squeeze push them into the part).
GRIP_KP = 1000.0  # N/m: the actuators' gain: the force limit reached once closed on a part
GRIP_FINGER_MASS = 0.1  # kg: each finger
# Colours (RGBA).
GRIPPER_RGBA = (0.3, 0.3, 0.35, 1)
TABLE_RGBA = (0.75, 0.7, 0.6, 1)

# Names in the model.
GRIPPER_BODY, MOCAP_BODY = "gripper", "target"
FINGER_JOINTS = ("finger_left", "finger_right")
TABLE_GEOM = "table"


@dataclass(frozen=True)
class Grip:
    """A real gripper's grip: friction, the sliding friction of the fingers' pads; force, N each finger squeezes at
    most."""

    friction: float
    force: float


def v(values) -> str:
    """Numbers as the MJCF writes them: space-separated, in their shortest form."""
    return " ".join(f"{v:g}" for v in values)


def gripper_xml(finger_open: float = FINGER_OPEN, grip: Grip | None = None) -> str:
    """The gripper's MJCF: the mocap target and a free body (palm and two fingers sliding apart along x, each by up
    to `finger_open` m; with a real `grip`, GRIP_FINGER_MASS each and padded with its friction) welded softly to it,
    both at GRIPPER_HOME; the `<equality>` and `<actuator>` blocks follow with gripper_constraints_xml."""
    fh, ph = FINGER_HALF, PALM_HALF
    finger = f'mass="{FINGER_MASS:g}"' if grip is None else (
        f'mass="{GRIP_FINGER_MASS:g}" friction="{grip.friction:g} 0.005 0.0001"'
    )  # fmt: skip
    fingers = "".join(
        f'<body name="{name}_body" pos="{sign * fh[0]:g} 0 {-(ph[2] + fh[2]):g}">'
        f'<joint name="{name}" type="slide" axis="{sign} 0 0" range="0 {finger_open:g}" damping="5"/>'
        f'<geom name="{name}_geom" type="box" size="{v(fh)}" {finger} rgba="{v(GRIPPER_RGBA)}"/></body>'
        for name, sign in zip(FINGER_JOINTS, (-1, 1))
    )
    return f"""<body name="{MOCAP_BODY}" mocap="true" pos="{v(GRIPPER_HOME)}"/>
    <body name="{GRIPPER_BODY}" pos="{v(GRIPPER_HOME)}" gravcomp="1">
      <freejoint/>
      <geom name="palm" type="box" size="{v(ph)}" mass="0.2" rgba="{v(GRIPPER_RGBA)}"/>
      {fingers}
    </body>"""


def gripper_constraints_xml(finger_open: float = FINGER_OPEN, grip: Grip | None = None) -> str:
    """The weld of the gripper to the mocap target and the fingers' position actuators (range 0 to `finger_open`):
    FINGER_KP, unlimited; with a real `grip`, GRIP_KP within its force and the fingers moving together."""
    gain, together = f'kp="{FINGER_KP:g}"', ""
    if grip is not None:
        gain = f'kp="{GRIP_KP:g}" forcelimited="true" forcerange="{-grip.force:g} {grip.force:g}"'
        together = f'\n    <joint joint1="{FINGER_JOINTS[0]}" joint2="{FINGER_JOINTS[1]}"/>'
    actuators = "".join(
        f'<position name="{name}" joint="{name}" {gain} ctrlrange="0 {finger_open:g}"/>' for name in FINGER_JOINTS
    )
    return f"""<equality>
    <weld body1="{MOCAP_BODY}" body2="{GRIPPER_BODY}" solref="{v(WELD_SOLREF)}"/>{together}
  </equality>
  <actuator>{actuators}</actuator>"""


def visual_xml(width: int, height: int) -> str:
    """The render settings: an offscreen buffer of the frame's size (pixels), shadows off, a soft headlight."""
    return f"""<visual>
    <global offwidth="{width}" offheight="{height}"/>
    <quality shadowsize="0"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.5 0.5 0.5"/>
  </visual>"""
