"""How a pick-and-place episode is drawn (sim.drawing): the table, the mats, the cups where they stand (moved when the
table changes; a layout whose cue is a tile draws none), the object on its poses, the change, the outcome."""

from __future__ import annotations

from cnep.sim import scene as S
from cnep.sim.drawing import Drawing, Note, Shape, table
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.layout import CUPS, PickLayout
from cnep.sim.tasks.pick_place.scoring import PickEpisode

FLAT = 0.001  # m: the half height of the mats


def drawing(ep: PickEpisode, layout: PickLayout = P.BAR) -> Drawing:
    """Episode `ep` in `layout` drawn (module docstring)."""
    places = layout.places
    mats = Shape(
        "mats",
        tuple((*xy, FLAT) for _, xy, _ in places),
        tuple((*layout.place_half(i), FLAT) for i in range(len(places))),
        layout.mat_rgba[0],
        labels=layout.names,
    )
    bar = Shape("bar", ((0.0, 0.0, 0.0),), (layout.object_half,), layout.object_rgba, solid=True)
    shown = layout.cue == CUPS
    changes = {0: (cups(ep.taken_start, layout),)} if shown else {}
    notes = {}
    if ep.change_step is not None:
        if shown:
            changes[ep.change_step] = (cups(ep.taken_end, layout),)
        notes[ep.change_step] = Note("the table changes")
    far = max(xy[1] + max(layout.place_half(i)) for i, (_, xy, _) in enumerate(places))
    view = ((-S.TABLE_HALF[0], S.TABLE_HALF[0]), (P.START[1] - 0.08, far + 0.05))
    return Drawing((table(), mats), bar, outcome(ep), view, changes=changes, notes=notes)


def cups(taken: list[bool], layout: PickLayout = P.BAR) -> Shape:
    """The cups standing on the places `taken` (a bool per place of `layout`)."""
    centres = tuple((*xy, P.CUP_HALF_HEIGHT) for (_, xy, _), t in zip(layout.places, taken) if t)
    half = (P.CUP_RADIUS, P.CUP_RADIUS, P.CUP_HALF_HEIGHT)
    return Shape("cups", centres, (half,) * len(centres), P.CUP_RGBA, solid=True, disc=True)


def outcome(ep: PickEpisode) -> str:
    """How the episode ended, in one line."""
    if ep.success:
        return f"success, the bar on {ep.place}"
    what = "a cup touched" if ep.collision else "dropped" if ep.dropped else "never lifted" if not ep.lifted else ""
    where = f"the bar on {ep.place}" if ep.place else "the bar on no mat"
    return f"failure, {', '.join(filter(None, (what, where)))} (valid: {', '.join(ep.valid) or 'none'})"
