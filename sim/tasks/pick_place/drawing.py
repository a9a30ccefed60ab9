"""How a pick-and-place episode is drawn (sim.drawing): the table, the mats, the cups where they stand (moved when the
table changes), the bar on its poses, the change, the outcome."""

from __future__ import annotations

from cnep.sim import scene as S
from cnep.sim.drawing import Drawing, Note, Shape, table
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.scoring import PickEpisode

FLAT = 0.001  # m: the half height of the mats


def drawing(ep: PickEpisode) -> Drawing:
    """Episode `ep` drawn (module docstring)."""
    mats = Shape(
        "mats",
        tuple((*xy, FLAT) for _, xy, _ in P.PLACES),
        tuple((*P.mat_half(i), FLAT) for i in range(len(P.PLACES))),
        P.MAT_RGBA,
        labels=tuple(name for name, _, _ in P.PLACES),
    )
    bar = Shape("bar", ((0.0, 0.0, 0.0),), (P.OBJECT_HALF,), P.OBJECT_RGBA, solid=True)
    changes = {0: (cups(ep.taken_start),)}
    notes = {}
    if ep.change_step is not None:
        changes[ep.change_step] = (cups(ep.taken_end),)
        notes[ep.change_step] = Note("the table changes")
    far = max(xy[1] + max(P.mat_half(i)) for i, (_, xy, _) in enumerate(P.PLACES))
    view = ((-S.TABLE_HALF[0], S.TABLE_HALF[0]), (P.START[1] - 0.08, far + 0.05))
    return Drawing((table(), mats), bar, outcome(ep), view, changes=changes, notes=notes)


def cups(taken: list[bool]) -> Shape:
    """The cups standing on the places `taken` (a bool per place)."""
    centres = tuple((*xy, P.CUP_HALF_HEIGHT) for (_, xy, _), t in zip(P.PLACES, taken) if t)
    half = (P.CUP_RADIUS, P.CUP_RADIUS, P.CUP_HALF_HEIGHT)
    return Shape("cups", centres, (half,) * len(centres), P.CUP_RGBA, solid=True, disc=True)


def outcome(ep: PickEpisode) -> str:
    """How the episode ended, in one line."""
    if ep.success:
        return f"success, the bar on {ep.place}"
    what = "a cup touched" if ep.collision else "dropped" if ep.dropped else "never lifted" if not ep.lifted else ""
    where = f"the bar on {ep.place}" if ep.place else "the bar on no mat"
    return f"failure, {', '.join(filter(None, (what, where)))} (valid: {', '.join(ep.valid) or 'none'})"
