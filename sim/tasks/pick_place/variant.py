"""Another pick-and-place task from its scene: `layout_task` makes the `task(version)` (sim.task.Task) of an environment
that runs PickPlaceEnv in another layout (sim.tasks.pick_place.layout) on the v1 robot and scenes (its own settings of
that version, the only one such a task has), its demonstrations the scripted demonstrator's in closed loop to its
plan's end (demonstrator.expert_to_plan_end), its scoring and drawing the pick-and-place task's in that layout."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

from cnep.sim.task import Task
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.demonstrator import demonstrations, expert_to_plan_end
from cnep.sim.tasks.pick_place.drawing import drawing
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.layout import PickLayout
from cnep.sim.tasks.pick_place.scoring import COLUMNS, describe_demonstrations, pick_rates, pick_row

LAYOUT_VERSION = (
    1  # the environments' version another layout's task runs: a robot's constraints, the change in the carry
)


def layout_task(
    name: str, env_id: str, env: type[PickPlaceEnv], layout: PickLayout, max_steps: int
) -> Callable[[int], Task]:
    """`task(version)` of the task `name` (registered as `env_id`) of `env` (a PickPlaceEnv in `layout`, its condition
    the first argument), episodes of `max_steps` control steps: its Task on LAYOUT_VERSION, ValueError for another."""

    def make_env(condition: str, max_steps: int) -> PickPlaceEnv:
        """The environment of an evaluation in `condition` (decided, free or changed)."""
        return env(condition, max_steps=max_steps)

    built = Task(
        name=name,
        version=LAYOUT_VERSION,
        env_id=env_id,
        max_steps=max_steps,
        conditions=P.CONDITIONS,
        variants=(),
        behaviours=layout.names,
        make_env=make_env,
        demonstrations=partial(demonstrations, make_env=env, drive=expert_to_plan_end),
        describe_demonstrations=partial(describe_demonstrations, layout=layout),
        row=pick_row,
        rates=pick_rates,
        columns=COLUMNS,
        drawing=partial(drawing, layout=layout),
    )

    def task(version: int) -> Task:
        """The task on the environments' `version` (LAYOUT_VERSION only)."""
        if version != LAYOUT_VERSION:
            raise ValueError(f"the {name} task runs the environments' version {LAYOUT_VERSION} only, got {version}")
        return built

    return task
