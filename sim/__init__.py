"""The simulator (the `sim` extra: MuJoCo and Gymnasium): the tabletop tasks as Gymnasium environments.

    import gymnasium, cnep.sim
    env = gymnasium.make("cnep/Obstacle-v0")          # or "cnep/ObstacleCue-v0": a tile shows the side to pass
    env = gymnasium.make("cnep/PickPlace-v0")         # pick a bar, put it on a free mat it fits (condition=...)
    env = gymnasium.make("cnep/PickPlace-v1")         # -v1 of each: a robot's limits and noise, wider scenes, a change
    observation, info = env.reset(seed=0)             #   during the motion (sim.robot, each task's versions)
    env = gymnasium.make("cnep/PickCube-v1")          # other pick-and-place scenes on v1's robot: a cube, three mats
    env = gymnasium.make("cnep/PickCan-v1")           #   and a tile's colour; a can, two mats and a cup

Each task is a folder of sim/tasks (its scene, environment, demonstrator, scoring and drawing) and a `Task`
(sim.task) the pipeline runs on one of its environment's versions: `cnep.sim.tasks.find_task("pick-place", 1)`.
Rendering is headless: MUJOCO_GL defaults to `egl` here, before MuJoCo loads (sim.render). This package imports the
standard library, numpy, MuJoCo, Gymnasium and cnep.runtime only (tests/test_architecture.py checks it).
"""

import importlib
import importlib.util
import os

from cnep.sim.errors import SimError

os.environ.setdefault("MUJOCO_GL", "egl")

ENV_ID, CUE_ENV_ID = "cnep/Obstacle-v0", "cnep/ObstacleCue-v0"
PICK_ENV_ID = "cnep/PickPlace-v0"
# The versions with a robot's constraints: the arm's limits, sensing noise, wider scenes, a change during the motion.
ENV_V1_ID, CUE_ENV_V1_ID, PICK_ENV_V1_ID = "cnep/Obstacle-v1", "cnep/ObstacleCue-v1", "cnep/PickPlace-v1"
PICK_CUBE_ENV_ID, PICK_CAN_ENV_ID = "cnep/PickCube-v1", "cnep/PickCan-v1"  # pick and place in other layouts
EXTRA = ("mujoco", "gymnasium")  # what the `sim` extra installs

_MODULES = {
    "tasks.obstacle.demonstrator": ("demonstration_path", "DemoDraw", "draw_demonstration"),
    "tasks.obstacle.env": ("IMAGE_KEY", "SIDES", "ObstacleEnv"),
    "episode": ("EpisodeResult", "PLANNED", "ONLINE", "PROTOCOLS", "run_episode"),
    "tasks.obstacle.scoring": ("ObstacleEpisode",),
    "tasks.pick_place.scoring": ("PickEpisode",),
    "tasks.pick_place.env": ("PICK_IMAGE_KEY", "PickPlaceEnv", "grasp_places"),
    "tasks.pick_place.demonstrator": ("PickDraw", "draw_pick", "pick_path"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(
    [*_WHERE, "CUE_ENV_ID", "CUE_ENV_V1_ID", "ENV_ID", "ENV_V1_ID", "PICK_CAN_ENV_ID", "PICK_CUBE_ENV_ID",
     "PICK_ENV_ID", "PICK_ENV_V1_ID", "SimError", "require_extra"]
)  # fmt: skip


def require_extra() -> None:
    """Raise SimError, one line saying how to install them, when MuJoCo or Gymnasium is missing, or naming MUJOCO_GL
    when MuJoCo cannot load the backend it names (sim.render.load_mujoco)."""
    missing = [name for name in EXTRA if importlib.util.find_spec(name) is None]
    if missing:
        raise SimError(
            f"the simulator needs {' and '.join(missing)}, which are not installed: pip install 'cnep-pipeline[sim]'"
        )
    importlib.import_module(f"{__name__}.render").load_mujoco()


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    require_extra()
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)


def _register() -> None:
    """Every environment registered with Gymnasium by its id (nothing is imported until one is made)."""
    import gymnasium

    obstacle, pick = "cnep.sim.tasks.obstacle.env:ObstacleEnv", "cnep.sim.tasks.pick_place.env:PickPlaceEnv"
    for env_id, entry_point, kwargs in (
        (ENV_ID, obstacle, {}),
        (CUE_ENV_ID, obstacle, {"cue": True}),
        (PICK_ENV_ID, pick, {}),
        (ENV_V1_ID, obstacle, {"version": 1}),
        (CUE_ENV_V1_ID, obstacle, {"cue": True, "version": 1}),
        (PICK_ENV_V1_ID, pick, {"version": 1}),
        (PICK_CUBE_ENV_ID, "cnep.sim.tasks.pick_cube.env:PickCubeEnv", {}),
        (PICK_CAN_ENV_ID, "cnep.sim.tasks.pick_can.env:PickCanEnv", {}),
    ):
        gymnasium.register(id=env_id, entry_point=entry_point, kwargs=kwargs)


if importlib.util.find_spec("gymnasium") is not None:
    _register()
