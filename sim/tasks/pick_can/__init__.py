"""The pick-a-can task: a short can to the free one of two mats, a cup taking the other (sim.tasks.pick_can.scene), the
pick-and-place task's environment, demonstrator and scoring in this layout: `task(version)` (sim.task.Task, on the
environments' version 1). The held-out task: a new task's study reports here what it tuned on pick-cube."""

from cnep.sim import PICK_CAN_ENV_ID
from cnep.sim.tasks.pick_can.env import PickCanEnv
from cnep.sim.tasks.pick_can.scene import LAYOUT, VERSION
from cnep.sim.tasks.pick_place.variant import layout_task

task = layout_task("pick-can", PICK_CAN_ENV_ID, PickCanEnv, LAYOUT, VERSION.max_steps)
