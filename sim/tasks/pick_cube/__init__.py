"""The pick-a-cube task: a cube to a coloured mat of three, a tile showing the colour (sim.tasks.pick_cube.scene), the
pick-and-place task's environment, demonstrator and scoring in this layout: `task(version)` (sim.task.Task, on the
environments' version 1). The task for choosing settings: a new task's study is tuned here and reported on pick-can."""

from cnep.sim import PICK_CUBE_ENV_ID
from cnep.sim.tasks.pick_cube.env import PickCubeEnv
from cnep.sim.tasks.pick_cube.scene import LAYOUT, VERSION
from cnep.sim.tasks.pick_place.variant import layout_task

task = layout_task("pick-cube", PICK_CUBE_ENV_ID, PickCubeEnv, LAYOUT, VERSION.max_steps)
