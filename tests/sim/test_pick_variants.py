"""The pick-and-place tasks in other layouts (pick-cube, pick-can): their scripted demonstrator solves every kind of
scene (the state alone, no frames rendered), the change moves the cue to another valid place, and each environment
passes Gymnasium's checker."""

import importlib.util

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import gymnasium  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from cnep.sim.paths import rollout  # noqa: E402
from cnep.sim.tasks import TASK_NAMES, find_task  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import pick_expert  # noqa: E402
from cnep.sim.tasks.pick_place.layout import TILE_BODY  # noqa: E402

VARIANTS = ("pick-cube", "pick-can")
SEEDS = 2  # per task and kind of scene


def test_the_variants_are_tasks():
    assert set(VARIANTS) <= set(TASK_NAMES)


@pytest.mark.parametrize("name", VARIANTS)
@pytest.mark.parametrize("condition", P.CONDITIONS)
def test_the_demonstrator_solves_every_scene(name, condition):
    env = gymnasium.make(find_task(name, 1).env_id, condition=condition, frames=False).unwrapped
    for seed in range(SEEDS):
        _, info = env.reset(seed=seed)
        valid = info["valid"]
        info, steps = rollout(env, pick_expert(env, info, np.random.default_rng(seed)).action, info)
        assert info["is_success"] and steps < env.max_steps, f"seed {seed}: {info}"
        assert (info["change_step"] is not None) == (condition == P.CHANGED)
        if condition != P.FREE:
            assert len(valid) == 1 and len(info["valid"]) == 1
            assert (info["valid"] != valid) == (condition == P.CHANGED)
    env.close()


@pytest.mark.parametrize("env_id", [cnep.sim.PICK_CUBE_ENV_ID, cnep.sim.PICK_CAN_ENV_ID])
def test_the_environment_passes_gymnasiums_checker(env_id):
    env = gymnasium.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_the_tile_takes_the_colour_of_the_valid_mat_and_hides_when_any_will_do():
    env = gymnasium.make(cnep.sim.PICK_CUBE_ENV_ID, condition=P.DECIDED, frames=False).unwrapped
    layout, tile = env.layout, env.model.geom(TILE_BODY)
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert tuple(env.model.geom_rgba[tile.id]) == pytest.approx(layout.mat_rgba[info["valid"][0]])
        assert env.data.geom(TILE_BODY).xpos[2] > 0
    env.close()
    env = gymnasium.make(cnep.sim.PICK_CUBE_ENV_ID, condition=P.FREE, frames=False).unwrapped
    _, info = env.reset(seed=0)
    assert len(info["valid"]) == 3 and env.data.geom(TILE_BODY).xpos[2] < 0
    env.close()
