"""The pick-and-place task: pick a bar and put it on a free mat it fits, the table deciding the place, leaving it
free, or changing during the motion: `TASK` (sim.task.Task)."""

from cnep.sim import PICK_ENV_ID
from cnep.sim.task import Task
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.demonstrator import demonstrations
from cnep.sim.tasks.pick_place.drawing import drawing
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.scoring import COLUMNS, describe_demonstrations, pick_rates, pick_row


def make_env(condition: str, max_steps: int) -> PickPlaceEnv:
    """The environment of an evaluation in `condition` (decided, free or changed)."""
    return PickPlaceEnv(condition, max_steps=max_steps)


TASK = Task(
    name="pick-place",
    env_id=PICK_ENV_ID,
    max_steps=P.MAX_STEPS,
    conditions=P.CONDITIONS,
    variants=(),
    behaviours=tuple(name for name, _, _ in P.PLACES),
    make_env=make_env,
    demonstrations=demonstrations,
    describe_demonstrations=describe_demonstrations,
    row=pick_row,
    rates=pick_rates,
    columns=COLUMNS,
    drawing=drawing,
)
