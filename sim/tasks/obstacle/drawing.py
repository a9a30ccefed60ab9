"""How an obstacle episode is drawn (sim.drawing): the table, the goal, the cue tile where it showed, the box on its
poses, the first contact with the box marked on the gripper, the outcome."""

from __future__ import annotations

from cnep.sim import scene as S
from cnep.sim.drawing import Drawing, Note, Shape, table
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.scoring import ObstacleEpisode

FLAT = 0.001  # m: the half height of the flat markers on the table (the goal, the cue)


def drawing(ep: ObstacleEpisode) -> Drawing:
    """Episode `ep` drawn (module docstring)."""
    shapes = [
        table(),
        Shape("goal", ((*O.GOAL_XY, FLAT),), ((O.GOAL_RADIUS, O.GOAL_RADIUS, FLAT),), O.GOAL_RGBA, disc=True),
    ]
    if ep.cue_side is not None:
        cue = (O.CUE_XY[0] * O.SIDE_SIGN[ep.cue_side], O.CUE_XY[1], FLAT)
        shapes.append(Shape("cue", (cue,), ((O.CUE_HALF, O.CUE_HALF, FLAT),), O.CUE_RGBA))
    box = Shape("box", ((0.0, 0.0, 0.0),), (O.BOX_HALF,), O.BOX_RGBA, solid=True)
    outcome = "success" if ep.success else "collision" if ep.collision else "missed the goal"
    outcome += (
        f", passed {ep.side}, min clearance {ep.clearance_m * 100:.1f} cm, {ep.distance_to_goal_m * 100:.1f} cm from "
        f"the goal"
    )
    notes = {} if ep.contact_step is None else {ep.contact_step: Note("the gripper touches the box", mark=True)}
    view = ((-S.TABLE_HALF[0], S.TABLE_HALF[0]), (O.START_Y - 0.08, O.GOAL_Y + 0.08))
    return Drawing(tuple(shapes), box, outcome, view, notes=notes)
