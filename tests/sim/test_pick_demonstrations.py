"""The pick-and-place tasks' demonstrations, one function driving each from its own reset as the task has it: v0 its
path open loop to its end, v1 the demonstrator in closed loop to the episode's end, another layout's to its plan's end;
each the same as that drive step by step with the same seed."""

import importlib.util

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.runtime import STATE_KEY  # noqa: E402
from cnep.sim.paths import rollout  # noqa: E402
from cnep.sim.task import demonstration_seed  # noqa: E402
from cnep.sim.tasks import find_task  # noqa: E402
from cnep.sim.tasks.pick_cube.env import PickCubeEnv  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import draw_pick, pick_expert, pick_path  # noqa: E402
from cnep.sim.tasks.pick_place.env import PickPlaceEnv  # noqa: E402

SEED = 5


def path_to_its_end(env, info, rng, seen):
    scene = env.scene
    draw = draw_pick(rng, scene["orientation"], scene["taken"])
    for action in pick_path(draw, seen[0][STATE_KEY][:3], scene["object_xy"], scene["object_yaw"]):
        seen.append(env.step(action.astype(np.float32))[0])


def expert_to_the_episodes_end(env, info, rng, seen):
    _, steps = rollout(env, pick_expert(env, info, rng).action, info, seen)
    assert env.unwrapped._steps == steps


def expert_to_its_plans_end(env, info, rng, seen):
    expert = pick_expert(env, info, rng)
    while expert.plan.given < len(expert.plan.waypoints):
        observation, _, _, truncated, info = env.step(expert.action(info))
        seen.append(observation)
        assert not truncated


@pytest.mark.parametrize(
    "name, version, make_env, by_hand",
    [
        ("pick-place", 0, lambda: PickPlaceEnv(version=0), path_to_its_end),
        ("pick-place", 1, lambda: PickPlaceEnv(version=1), expert_to_the_episodes_end),
        ("pick-cube", 1, PickCubeEnv, expert_to_its_plans_end),
    ],
)
def test_a_tasks_demonstration_is_its_drive_step_by_step(name, version, make_env, by_hand):
    (made,) = find_task(name, version).demonstrations(1, SEED)
    env = make_env()
    observation, info = env.reset(seed=demonstration_seed(SEED, 0))
    seen = [observation]
    by_hand(env, info, np.random.default_rng(SEED), seen)
    env.close()
    assert np.array_equal(made.states, np.stack([o[STATE_KEY] for o in seen]))
    assert np.array_equal(made.frames, np.stack([o[env.image_key] for o in seen]))
