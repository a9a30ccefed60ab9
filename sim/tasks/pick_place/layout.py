"""A pick-and-place scene's description (`PickLayout`): the object to pick, the places, the cue that decides the
place and the camera, and its MJCF (`layout_xml`). The pick-and-place task's own is sim.tasks.pick_place.scene.BAR;
other tasks describe theirs with the same fields and run the same environment, demonstrator and scoring.

The cue decides which of the grasp's places are valid: CUPS, a cup standing on a mat takes that place; TILE, a tile
at `tile_xy` takes the colour of the one valid place's mat (hidden when the grasp has several). What is not in the
layout (the gripper's heights, the phases' steps, the conditions) is the scene module's, shared by every layout.
Units: metres, degrees; the table's top is z = 0; facing +y, left is -x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cnep.sim import scene as S

BOX, CYLINDER = "box", "cylinder"  # the object's shapes
CUPS, TILE = "cups", "tile"  # the cues
RGBA = tuple[float, float, float, float]


@dataclass(frozen=True)
class PickLayout:
    """One pick-and-place scene.

    model: the MJCF's model name; shape: BOX or CYLINDER (upright); object_half: half sizes (m) in its own frame, the
    fingers closing across x (a cylinder: radius, radius, half height); object_rgba; object_xy: where it lies (m),
    within the version's jitter; orientations: its orientation's name -> its yaw (degrees) = the grasp's yaw; places:
    (name, mat centre (x, y) m, the orientation whose object the mat takes) each; mat_half: a mat's half sizes across
    and along its long side (m), the long side along y for an orientation of yaw 0, else along x; mat_rgba: one per
    place; cue: CUPS or TILE; tile_xy, tile_half: where the tile lies and its half sizes (m); grasp_offset: the
    demonstrator's grasp point drawn within this of the object's centre along its y (m); camera: its position (m),
    pitch from straight down (towards +y before the yaw), yaw about z (degrees, 0: looking along +y) and vertical
    field of view (degrees).
    """

    model: str
    shape: str
    object_half: tuple[float, float, float]
    object_rgba: RGBA
    object_xy: tuple[float, float]
    orientations: dict[str, float]
    places: tuple[tuple[str, tuple[float, float], str], ...]
    mat_half: tuple[float, float]
    mat_rgba: tuple[RGBA, ...]
    cue: str
    tile_xy: tuple[float, float]
    tile_half: tuple[float, float]
    grasp_offset: float
    camera_pos: tuple[float, float, float]
    camera_pitch_deg: float
    camera_yaw_deg: float
    camera_fovy: float

    def __post_init__(self) -> None:
        if self.shape not in (BOX, CYLINDER) or self.cue not in (CUPS, TILE):
            raise ValueError(f"a layout's shape is {BOX} or {CYLINDER} and its cue {CUPS} or {TILE}")
        if len(self.mat_rgba) != len(self.places) or any(o not in self.orientations for _, _, o in self.places):
            raise ValueError("a layout has a mat colour per place, each place taking one of its orientations")

    @property
    def names(self) -> tuple[str, ...]:
        """The places' names."""
        return tuple(name for name, _, _ in self.places)

    def place_half(self, place: int) -> tuple[float, float]:
        """Place `place`'s mat's half sizes along x and y (m)."""
        across, along = self.mat_half
        return (across, along) if self.orientations[self.places[place][2]] == 0 else (along, across)

    def grasp_places(self, orientation: str) -> tuple[int, ...]:
        """The places (indices of places) an object lying `orientation` fits."""
        return tuple(i for i, (_, _, fits) in enumerate(self.places) if fits == orientation)


def cup_body(place: int) -> str:
    """The name of the cup (a mocap body) that takes place `place`."""
    return f"cup_{place}"


TILE_BODY = "cue_tile"


def camera_xml(name: str, layout: PickLayout) -> str:
    """The layout's camera `name`: at camera_pos, pitched from straight down towards its yaw's direction."""
    pitch, yaw = math.radians(layout.camera_pitch_deg), math.radians(layout.camera_yaw_deg)
    x_axis = (math.cos(yaw), math.sin(yaw), 0.0)
    y_axis = (-math.sin(yaw) * math.cos(pitch), math.cos(yaw) * math.cos(pitch), math.sin(pitch))
    axes = " ".join(f"{a:.4f}" for a in (*x_axis, *y_axis))
    return f'<camera name="{name}" pos="{S.v(layout.camera_pos)}" xyaxes="{axes}" fovy="{layout.camera_fovy:g}"/>'
