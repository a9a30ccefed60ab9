"""The pick-a-cube task's tabletop (`LAYOUT`, sim.tasks.pick_place.layout; `VERSION`, the pick-and-place v1 robot with
the cube's weight): a cube to put on one of three coloured mats in a row beyond it; a tile in front of the table
takes the colour of the mat to use (hidden when any will do); the camera looks from the front right. Units: metres,
degrees, kilograms.
"""

from dataclasses import replace

from cnep.sim.tasks.pick_place.layout import BOX, TILE, PickLayout
from cnep.sim.tasks.pick_place.versions import V1

LAYOUT = PickLayout(
    model="cnep-pick-cube",
    shape=BOX,
    object_half=(0.02, 0.02, 0.02),
    object_rgba=(0.55, 0.2, 0.7, 1),
    object_xy=(0.0, -0.08),
    orientations={"upright": 0.0},
    places=(("red", (-0.22, 0.17), "upright"), ("green", (0.0, 0.25), "upright"), ("yellow", (0.22, 0.17), "upright")),
    mat_half=(0.05, 0.05),
    mat_rgba=((0.8, 0.2, 0.2, 1), (0.2, 0.65, 0.3, 1), (0.85, 0.8, 0.2, 1)),
    cue=TILE,
    tile_xy=(-0.22, -0.16),
    tile_half=(0.04, 0.04),
    grasp_offset=0.005,
    camera_pos=(0.5, -0.38, 0.72),
    camera_pitch_deg=42.0,
    camera_yaw_deg=50.0,
    camera_fovy=50.0,
)
VERSION = replace(V1, object_mass=0.1)  # kg: a wooden cube of 4 cm (64 cm³ at about 1.5 g/cm³)
