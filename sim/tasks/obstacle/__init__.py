"""The obstacle task: from a start to the goal past a box, on either side (a cue tile showing the side in its
variant): `TASK` (sim.task.Task)."""

from cnep.sim import ENV_ID
from cnep.sim.task import Task
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.demonstrator import demonstrations
from cnep.sim.tasks.obstacle.drawing import drawing
from cnep.sim.tasks.obstacle.env import ObstacleEnv
from cnep.sim.tasks.obstacle.scoring import COLUMNS, describe_demonstrations, episode_row, rates


def make_env(condition: str | None, max_steps: int, cue: bool = False) -> ObstacleEnv:
    """The environment of an evaluation (the task has no conditions: `condition` is None)."""
    if condition is not None:
        raise ValueError(f"the obstacle task has no conditions, got {condition!r}")
    return ObstacleEnv(cue=cue, max_steps=max_steps)


TASK = Task(
    name="obstacle",
    env_id=ENV_ID,
    max_steps=O.MAX_STEPS,
    conditions=(),
    variants=("cue",),
    behaviours=O.SIDES,
    make_env=make_env,
    demonstrations=demonstrations,
    describe_demonstrations=describe_demonstrations,
    row=episode_row,
    rates=rates,
    columns=COLUMNS,
    drawing=drawing,
)
