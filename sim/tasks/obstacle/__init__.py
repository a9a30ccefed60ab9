"""The obstacle task: from a start to the goal past a box, on either side (a cue tile showing the side in its
variant): `task(version)` (sim.task.Task) on the environment's version (versions.py)."""

from functools import partial

from cnep.sim import CUE_ENV_ID, CUE_ENV_V1_ID, ENV_ID, ENV_V1_ID
from cnep.sim.task import Task
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.demonstrator import demonstrations
from cnep.sim.tasks.obstacle.drawing import drawing
from cnep.sim.tasks.obstacle.env import ObstacleEnv
from cnep.sim.tasks.obstacle.scoring import COLUMNS, describe_demonstrations, episode_row, rates
from cnep.sim.tasks.obstacle.versions import version_of

ENV_IDS = ((ENV_ID, CUE_ENV_ID), (ENV_V1_ID, CUE_ENV_V1_ID))  # per version: without the cue, with it


def make_env(condition: str | None, max_steps: int, cue: bool = False, version: int = 0) -> ObstacleEnv:
    """The environment of an evaluation (the task has no conditions: `condition` is None)."""
    if condition is not None:
        raise ValueError(f"the obstacle task has no conditions, got {condition!r}")
    return ObstacleEnv(cue=cue, max_steps=max_steps, version=version)


def task(version: int) -> Task:
    """The task on the environment's `version` (ValueError for one it does not have)."""
    steps = version_of(version).max_steps
    return Task(
        name="obstacle",
        version=version,
        env_id=ENV_IDS[version][0],
        max_steps=steps,
        conditions=(),
        variants=("cue",),
        behaviours=O.SIDES,
        make_env=partial(make_env, version=version),
        demonstrations=partial(demonstrations, version=version),
        describe_demonstrations=describe_demonstrations,
        row=episode_row,
        rates=rates,
        columns=COLUMNS,
        drawing=drawing,
    )
