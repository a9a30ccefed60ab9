"""The simulator (the `sim` extra: MuJoCo and Gymnasium): the tabletop tasks as Gymnasium environments.

    import gymnasium, cnep.sim
    env = gymnasium.make("cnep/Obstacle-v0")          # or "cnep/ObstacleCue-v0": a tile shows the side to pass
    env = gymnasium.make("cnep/PickPlace-v0")         # pick a bar, put it on a free mat it fits (condition=...)
    observation, info = env.reset(seed=0)

Rendering is headless: MUJOCO_GL defaults to `egl` here, before MuJoCo loads (sim.render). This package imports
the standard library, numpy, MuJoCo, Gymnasium and cnep.runtime only (tests/test_architecture.py checks it).
"""

import importlib
import os

from cnep.sim.errors import SimError

os.environ.setdefault("MUJOCO_GL", "egl")

ENV_ID, CUE_ENV_ID = "cnep/Obstacle-v0", "cnep/ObstacleCue-v0"
PICK_ENV_ID = "cnep/PickPlace-v0"
EXTRA = ("mujoco", "gymnasium")  # what the `sim` extra installs

_MODULES = {
    "demonstrator": ("demonstration_path", "DemoDraw", "draw_demonstration"),
    "env": ("IMAGE_KEY", "SIDES", "ObstacleEnv"),
    "episode": ("EpisodeResult", "PLANNED", "ONLINE", "PROTOCOLS", "run_episode"),
    "pick_env": ("PICK_IMAGE_KEY", "PickPlaceEnv", "grasp_places"),
    "pick_demonstrator": ("PickDraw", "draw_pick", "pick_path"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted([*_WHERE, "CUE_ENV_ID", "ENV_ID", "PICK_ENV_ID", "SimError", "require_extra"])


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


if importlib.util.find_spec("gymnasium") is not None:  # registered by name: nothing is imported until made
    import gymnasium

    gymnasium.register(id=ENV_ID, entry_point="cnep.sim.env:ObstacleEnv")
    gymnasium.register(id=CUE_ENV_ID, entry_point="cnep.sim.env:ObstacleEnv", kwargs={"cue": True})
    gymnasium.register(id=PICK_ENV_ID, entry_point="cnep.sim.pick_env:PickPlaceEnv")
