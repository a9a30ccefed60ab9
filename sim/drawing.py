"""How an episode is drawn, in its Rerun recording and its figure: the task's shapes (boxes, or flat discs), its object
moved by the episode's poses, the shapes that change during the episode, notes at steps, the outcome. Positions and
sizes in metres, in the table's frame (sim.scene); colours RGBA in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field

from cnep.sim import scene as S


@dataclass(frozen=True)
class Shape:
    """Boxes sharing a name and a colour: centres and half_sizes, (x, y, z) each (m); labels, one per box (or none);
    solid: filled (else drawn as edges where the viewer can); disc: a flat round marker of radius half_sizes[0] (a
    box in the recording, a circle from above in the figure)."""

    name: str
    centres: tuple[tuple[float, float, float], ...]
    half_sizes: tuple[tuple[float, float, float], ...]
    rgba: tuple[float, float, float, float]
    labels: tuple[str, ...] = ()
    solid: bool = False
    disc: bool = False

    @property
    def rgb(self) -> tuple[int, int, int]:
        """The colour as 0-255 RGB."""
        return tuple(round(255 * c) for c in self.rgba[:3])


@dataclass(frozen=True)
class Note:
    """A line in the episode's log at its step; mark: also a mark on the gripper (a contact)."""

    text: str
    mark: bool = False


@dataclass(frozen=True)
class Drawing:
    """An episode drawn: shapes, static (the table first); obj, the task's object in its own frame (one box at the
    origin), moved at every step by the episode's object_poses; changes, step -> shapes shown from that step on (in
    place of those of the same name); notes, step -> Note; outcome, one line saying how it ended; view, the figure's
    x and y limits from above (m)."""

    shapes: tuple[Shape, ...]
    obj: Shape
    outcome: str
    view: tuple[tuple[float, float], tuple[float, float]]
    changes: dict[int, tuple[Shape, ...]] = field(default_factory=dict)
    notes: dict[int, Note] = field(default_factory=dict)


def table() -> Shape:
    """The table top every task stands on (sim.scene)."""
    return Shape(S.TABLE_GEOM, ((0.0, 0.0, -S.TABLE_HALF[2]),), (S.TABLE_HALF,), S.TABLE_RGBA)
