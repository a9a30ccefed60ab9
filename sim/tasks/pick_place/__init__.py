"""The pick-and-place task: pick a bar and put it on a free mat it fits, the table deciding the place, leaving it
free, or changing during the motion: `task(version)` (sim.task.Task) on the environment's version (versions.py)."""

from functools import partial

from cnep.sim import PICK_ENV_ID, PICK_ENV_V1_ID
from cnep.sim.task import Task
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.demonstrator import demonstrations, expert_to_episode_end, follow_path
from cnep.sim.tasks.pick_place.drawing import drawing
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.scoring import COLUMNS, describe_demonstrations, pick_rates, pick_row
from cnep.sim.tasks.pick_place.versions import version_of

ENV_IDS = (PICK_ENV_ID, PICK_ENV_V1_ID)  # per version
DRIVES = (follow_path, expert_to_episode_end)  # per version: how the scripted demonstrator drives the environment


def make_env(condition: str, max_steps: int, version: int = 0) -> PickPlaceEnv:
    """The environment of an evaluation in `condition` (decided, free or changed)."""
    return PickPlaceEnv(condition, max_steps=max_steps, version=version)


def task(version: int) -> Task:
    """The task on the environment's `version` (ValueError for one it does not have)."""
    steps = version_of(version).max_steps
    return Task(
        name="pick-place",
        version=version,
        env_id=ENV_IDS[version],
        max_steps=steps,
        conditions=P.CONDITIONS,
        variants=(),
        behaviours=tuple(name for name, _, _ in P.PLACES),
        make_env=partial(make_env, version=version),
        demonstrations=partial(demonstrations, make_env=partial(PickPlaceEnv, version=version), drive=DRIVES[version]),
        describe_demonstrations=describe_demonstrations,
        row=pick_row,
        rates=pick_rates,
        columns=COLUMNS,
        drawing=drawing,
    )
