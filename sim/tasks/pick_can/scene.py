"""The pick-a-can task's tabletop (`LAYOUT`, sim.tasks.pick_place.layout; `VERSION`, the pick-and-place v1 robot with
the can's weight): a short can standing upright, to put on one of two mats, one near on the left, one far on the
right; a cup standing on a mat takes it; the camera looks from high in front, a little from the left. Units: metres,
degrees, kilograms.
"""

from dataclasses import replace

from cnep.sim.tasks.pick_place.layout import CUPS, CYLINDER, PickLayout
from cnep.sim.tasks.pick_place.versions import V1

LAYOUT = PickLayout(
    model="cnep-pick-can",
    shape=CYLINDER,
    object_half=(0.024, 0.024, 0.025),
    object_rgba=(0.9, 0.55, 0.1, 1),
    object_xy=(0.02, -0.06),
    orientations={"upright": 0.0},
    places=(("near_left", (-0.25, -0.02), "upright"), ("far_right", (0.17, 0.25), "upright")),
    mat_half=(0.055, 0.055),
    mat_rgba=((0.3, 0.45, 0.6, 1),) * 2,
    cue=CUPS,
    tile_xy=(0.0, 0.0),
    tile_half=(0.0, 0.0),
    grasp_offset=0.004,
    camera_pos=(-0.12, -0.5, 0.9),
    camera_pitch_deg=28.0,
    camera_yaw_deg=-10.0,
    camera_fovy=46.0,
)
VERSION = replace(V1, object_mass=0.15)  # kg: a small filled can of 4.8 cm by 5 cm
