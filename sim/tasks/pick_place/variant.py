"""Another pick-and-place task from its scene: `layout_task` makes the `Task` (sim.task) of an environment that runs
PickPlaceEnv in another layout (sim.tasks.pick_place.layout) with its own version, its demonstrations the scripted
demonstrator's in closed loop (demonstrator.expert_demonstrations), its scoring and drawing the pick-and-place
task's in that layout."""

from __future__ import annotations

from functools import partial

from cnep.sim.task import Task
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.demonstrator import expert_demonstrations
from cnep.sim.tasks.pick_place.drawing import drawing
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.layout import PickLayout
from cnep.sim.tasks.pick_place.scoring import COLUMNS, describe_demonstrations, pick_rates, pick_row


def layout_task(name: str, env_id: str, env: type[PickPlaceEnv], layout: PickLayout, max_steps: int) -> Task:
    """The task `name` (registered as `env_id`) of `env` (a PickPlaceEnv in `layout`, its condition the first
    argument), episodes of `max_steps` control steps."""

    def make_env(condition: str, max_steps: int) -> PickPlaceEnv:
        """The environment of an evaluation in `condition` (decided, free or changed)."""
        return env(condition, max_steps=max_steps)

    return Task(
        name=name,
        env_id=env_id,
        max_steps=max_steps,
        conditions=P.CONDITIONS,
        variants=(),
        behaviours=layout.names,
        make_env=make_env,
        demonstrations=partial(expert_demonstrations, make_env=env),
        describe_demonstrations=partial(describe_demonstrations, layout=layout),
        row=pick_row,
        rates=pick_rates,
        columns=COLUMNS,
        drawing=partial(drawing, layout=layout),
    )
