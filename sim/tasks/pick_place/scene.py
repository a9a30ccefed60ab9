"""The pick-and-place task's tabletop: every size, position and margin as a named constant, and its MJCF.

A bar lies on the table, its long side along y or along x. The gripper (sim.scene's, its fingers sliding apart
along its own x) grasps it across its narrow side: with the home orientation (yaw 0) when it lies along y, turned
a quarter about z (yaw 90) when it lies along x. Four mats are the places: two long along y (the yaw-0 grasp's
places, left and right of the bar) and two long along x (the yaw-90 grasp's, beyond it). The bar is to be put down
lying as it lay, and fits a mat only lying along it, so each grasp has two places (turned in the air, it would
fit the others: that does not count). A cup standing on a mat takes that place. Units: metres, seconds,
kilograms; the table's top is z = 0; facing +y, left is -x.
"""

from __future__ import annotations

from cnep.sim import scene as S
from cnep.sim.tasks.pick_place.layout import BOX, CUPS, TILE_BODY, PickLayout, camera_xml, cup_body

# The bar to pick: half sizes in its own frame (long along its y), on the table near OBJECT_XY.
OBJECT_HALF = (0.0175, 0.07, 0.025)
OBJECT_MASS = 0.05  # kg
OBJECT_FRICTION = 2.0  # sliding friction of the bar (MuJoCo takes the larger of two touching geoms')
OBJECT_XY = (0.0, -0.08)  # m: where the bar lies, within OBJECT_JITTER on each axis
OBJECT_JITTER = 0.02  # m
YAW_JITTER_DEG = 5.0  # the bar's yaw within this of its orientation's (degrees)
ORIENTATIONS = {"along_y": 0.0, "along_x": 90.0}  # the bar's long side -> its yaw (degrees) = the grasp's yaw
# The places: name, mat centre (x, y), the orientation of the bar the mat takes (its long side).
PLACES = (
    ("left", (-0.26, 0.06), "along_y"),
    ("right", (0.26, 0.06), "along_y"),
    ("far_left", (-0.13, 0.27), "along_x"),
    ("far_right", (0.13, 0.27), "along_x"),
)
MAT_HALF = (0.04, 0.095)  # m: a mat's half sizes across and along its long side (the bar's: 0.0175, 0.07)
CUP_RADIUS, CUP_HALF_HEIGHT = 0.032, 0.05  # m: the cup that takes a place stands on its mat's centre
TILE_HALF_HEIGHT = 0.002  # m: the tile cue's (sim.tasks.pick_place.layout.TILE)
HIDDEN_Z = -1.0  # m: where a cup waits when no place needs it (under the table, out of view and of reach)
# The gripper: sim.scene's, opening wider so a grasp that misses the bar's centre by a little still takes it.
FINGER_OPEN = 0.04  # m: each finger's travel (the open gripper's gap: 0.08 m)
CLOSE_BELOW = FINGER_OPEN / 2  # a gripper command below this closes the fingers (driven to 0: they squeeze)
START = (0.0, -0.30, 0.2)  # m: the gripper's start, within START_JITTER on x and y
START_JITTER = 0.03  # m
GRASP_Z = 0.082  # m: the palm's centre when grasping (the fingers' bottoms 1.2 cm above the table)
CARRY_Z = 0.22  # m: the palm's centre while carrying (the bar's bottom above the cups' tops)
LIFTED_Z = 0.03  # m: the bar's centre this far above where it lay counts as lifted
DROP_HEIGHT = 0.02  # m: the bar out of the fingers with its bottom this far above the table was dropped
REST_SPEED = 0.02  # m/s: the bar at rest
MAX_STEPS = 90  # control steps of an episode (9 s): demonstrations take PHASE_STEPS' sum
# The scripted demonstrator (the task's demonstrator): per phase a number of control steps within these (inclusive),
# at one pace drawn per demonstration; approach (above the bar, turning to the grasp's yaw), descend, close, lift,
# carry, lower, open, leave.
PHASE_STEPS = {
    "approach": (12, 16),
    "descend": (6, 8),
    "close": (4, 5),
    "lift": (6, 8),
    "carry": (14, 18),
    "lower": (6, 8),
    "open": (3, 4),
    "leave": (5, 6),
}
GRASP_OFFSET = 0.015  # m: the grasp point drawn within this of the bar's centre, along its long side
PLACE_OFFSET = 0.01  # m: the place point drawn within this of the mat's centre on each axis
CARRY_JITTER = 0.02  # m: the carrying height drawn within this of CARRY_Z
# The conditions of an episode: `decided` (one of the grasp's two places taken), `free` (both free), `changed`
# (decided at the start, then at a step drawn from CHANGE_STEPS the cup moves to the other place of the grasp).
DECIDED, FREE, CHANGED = "decided", "free", "changed"
CONDITIONS = (DECIDED, FREE, CHANGED)
CHANGE_STEPS = (8, 24)  # inclusive: after the motion starts, before the bar reaches its place
OTHER_TAKEN = 0.5  # the chance that each place of the other grasp is taken (it decides nothing)
# The camera: in front of the table, looking down at the places; 4:3 frames, large enough for the cups and the bar.
CAMERA = "overhead"
IMAGE_WIDTH, IMAGE_HEIGHT = 224, 168
CAMERA_POS = (0.0, -0.42, 0.78)  # m
CAMERA_PITCH_DEG = 32.0  # from straight down, towards +y
CAMERA_FOVY = 42.0  # degrees
# Colours (RGBA).
OBJECT_RGBA = (0.15, 0.35, 0.85, 1)
MAT_RGBA = (0.35, 0.55, 0.35, 1)
CUP_RGBA = (0.9, 0.9, 0.85, 1)
# Names in the model.
OBJECT_BODY, OBJECT_GEOM = "bar", "bar"


# A real grip's friction holds without creeping (MuJoCo's soft contacts let a squeezed part slide slowly otherwise):
# elliptic friction cones, made stiffer than the normal force's.
GRIP_OPTIONS = ' cone="elliptic" impratio="10"'


BAR = PickLayout(
    model="cnep-pick-place",
    shape=BOX,
    object_half=OBJECT_HALF,
    object_rgba=OBJECT_RGBA,
    object_xy=OBJECT_XY,
    orientations=ORIENTATIONS,
    places=PLACES,
    mat_half=MAT_HALF,
    mat_rgba=(MAT_RGBA,) * len(PLACES),
    cue=CUPS,
    tile_xy=(0.0, 0.0),
    tile_half=(0.0, 0.0),
    grasp_offset=GRASP_OFFSET,
    camera_pos=CAMERA_POS,
    camera_pitch_deg=CAMERA_PITCH_DEG,
    camera_yaw_deg=0.0,
    camera_fovy=CAMERA_FOVY,
)  # the bar, its four mats and the cups: this task's layout


def scene_xml(layout: PickLayout = BAR, object_mass: float = OBJECT_MASS, grip: S.Grip | None = None) -> str:
    """The MJCF of `layout`: table, mats, the cue (cups or the tile, hidden), the object (free, `object_mass` kg; its
    friction OBJECT_FRICTION, or the real `grip`'s), the gripper of sim.scene (a real `grip`'s, or the idealised one),
    the camera."""
    v = S.v
    mats = "".join(
        f'<geom name="mat_{name}" type="box" pos="{v(xy)} 0.001" size="{v(layout.place_half(i))} 0.001" '
        f'rgba="{v(layout.mat_rgba[i])}" contype="0" conaffinity="0"/>'
        for i, (name, xy, _) in enumerate(layout.places)
    )
    if layout.cue == CUPS:
        cue = "".join(
            f'<body name="{cup_body(i)}" mocap="true" pos="{v(xy)} {HIDDEN_Z:g}">'
            f'<geom name="{cup_body(i)}" type="cylinder" size="{CUP_RADIUS:g} {CUP_HALF_HEIGHT:g}" '
            f'rgba="{v(CUP_RGBA)}"/></body>'
            for i, (_, xy, _) in enumerate(layout.places)
        )
    else:
        cue = (
            f'<body name="{TILE_BODY}" mocap="true" pos="{v(layout.tile_xy)} {HIDDEN_Z:g}">'
            f'<geom name="{TILE_BODY}" type="box" size="{v(layout.tile_half)} {TILE_HALF_HEIGHT:g}" '
            f'contype="0" conaffinity="0"/></body>'
        )
    size = layout.object_half if layout.shape == BOX else layout.object_half[1:]
    friction = OBJECT_FRICTION if grip is None else grip.friction
    return f"""<mujoco model="{layout.model}">
  <option timestep="{S.TIMESTEP_S:g}"{"" if grip is None else GRIP_OPTIONS}/>
  {S.visual_xml(IMAGE_WIDTH, IMAGE_HEIGHT)}
  <worldbody>
    <geom name="{S.TABLE_GEOM}" type="box" pos="0 0 {-S.TABLE_HALF[2]:g}" size="{v(S.TABLE_HALF)}"
      rgba="{v(S.TABLE_RGBA)}"/>
    {mats}
    {cue}
    {camera_xml(CAMERA, layout)}
    <body name="{OBJECT_BODY}" pos="{v(layout.object_xy)} {layout.object_half[2]:g}">
      <freejoint/>
      <geom name="{OBJECT_GEOM}" type="{layout.shape}" size="{v(size)}" mass="{object_mass:g}"
        friction="{friction:g} 0.005 0.0001" rgba="{v(layout.object_rgba)}"/>
    </body>
    {S.gripper_xml(FINGER_OPEN, grip)}
  </worldbody>
  {S.gripper_constraints_xml(FINGER_OPEN, grip)}
</mujoco>
"""
