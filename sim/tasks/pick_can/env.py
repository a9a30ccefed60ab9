"""`PickCanEnv`: the pick-a-can task as a Gymnasium environment (`gymnasium.make("cnep/PickCan-v1")`):
sim.tasks.pick_place.env.PickPlaceEnv in this task's layout, with its version (sim.tasks.pick_can.scene)."""

from cnep.sim.tasks.pick_can.scene import LAYOUT, VERSION
from cnep.sim.tasks.pick_place.env import MIXED, PickPlaceEnv


class PickCanEnv(PickPlaceEnv):
    """PickPlaceEnv in the pick-a-can layout with its version; `options`: PickPlaceEnv's render_mode, max_steps,
    latency_steps and frames."""

    def __init__(self, condition: str = MIXED, **options) -> None:
        super().__init__(condition, version=VERSION, layout=LAYOUT, **options)
