"""The pick-and-place environment: Gymnasium's checker, the scripted demonstrator putting the bar on a free mat it
fits, the physics' verdicts (a wrong place, a cup touched), and the changed scene."""

import importlib.util

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import gymnasium  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from cnep.runtime import STATE_KEY  # noqa: E402
from cnep.sim import PICK_ENV_ID, PICK_IMAGE_KEY, PickPlaceEnv, draw_pick, grasp_places, pick_path  # noqa: E402
from cnep.sim.scene import GRIPPER_BODY  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import phase_steps  # noqa: E402


@pytest.fixture(scope="module")
def env():
    env = PickPlaceEnv()
    yield env
    env.close()


def _demonstrate(env, seed, options=None, place=None):
    """Reset with `seed` and run the scripted demonstrator (to `place` when given) to the end; the last info."""
    observation, info = env.reset(seed=seed, options=options)
    taken = env.scene["taken"] if place is None else [False] * len(P.PLACES)
    draw = draw_pick(np.random.default_rng(seed), env.scene["orientation"], taken)
    if place is not None:
        draw = type(draw)(place, draw.steps, draw.grasp, draw.target, draw.carry_z)
    start = observation[STATE_KEY][:3]
    for action in pick_path(draw, start, env.scene["object_xy"], env.scene["object_yaw"]):
        observation, _, terminated, truncated, info = env.step(action.astype(np.float32))
        if terminated or truncated:
            break
    return info


def test_the_environment_passes_gymnasiums_checker_and_is_registered():
    env = gymnasium.make(PICK_ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)
    observation, info = env.reset(seed=0)
    assert observation[PICK_IMAGE_KEY].shape == (P.IMAGE_HEIGHT, P.IMAGE_WIDTH, 3)
    assert info["condition"] in (P.DECIDED, P.FREE) and info["valid"]
    env.close()


def test_a_demonstrators_pace_carries_through_its_whole_motion():
    assert phase_steps(0.0) == tuple(lo for lo, _ in P.PHASE_STEPS.values())
    assert phase_steps(1.0) == tuple(hi for _, hi in P.PHASE_STEPS.values())
    rng = np.random.default_rng(0)
    draws = [draw_pick(rng, "along_y", [False] * len(P.PLACES)).steps for _ in range(40)]
    assert len(set(draws)) > 5  # demonstrations vary in speed
    for steps in draws:  # and a quick one is quick in every phase: no phase is slower than in a slower draw
        for other in draws:
            if sum(other) > sum(steps) + len(steps):
                assert all(a <= b for a, b in zip(steps, other))


def test_the_scene_decides_where_one_place_of_the_grasp_is_taken_and_leaves_the_choice_where_none_is():
    decided, free = PickPlaceEnv(P.DECIDED), PickPlaceEnv(P.FREE)
    for seed in range(4):
        assert len(decided.reset(seed=seed)[1]["valid"]) == 1
        info = free.reset(seed=seed)[1]
        assert info["valid"] == list(grasp_places(info["orientation"]))
    decided.close()
    free.close()


@pytest.mark.slow
def test_the_demonstrator_puts_the_bar_on_a_free_mat_it_fits_and_the_same_seed_repeats_it(env):
    info = _demonstrate(env, 3)
    assert info["is_success"] and info["lifted"] and not info["dropped"] and not info["collision"]
    assert info["place"] in info["valid"]
    first = env.data.body(P.OBJECT_BODY).xpos.copy()
    _demonstrate(env, 3)
    np.testing.assert_array_equal(first, env.data.body(P.OBJECT_BODY).xpos)


def test_the_grasp_offset_is_how_far_the_gripper_was_from_the_bar_when_first_told_to_close(env):
    _, info = env.reset(seed=5)
    assert info["grasp_offset_m"] is None
    gripper, bar = env.data.body(GRIPPER_BODY).xpos.copy(), env.data.body(P.OBJECT_BODY).xpos[:2].copy()
    close_here = np.array([*gripper, 0, 0, 0, 0, 0.0], np.float32)  # a zero quaternion keeps the home orientation
    _, _, _, _, info = env.step(close_here)
    offset = float(np.linalg.norm(gripper[:2] - bar))
    assert info["grasp_offset_m"] == pytest.approx(offset, abs=1e-9) and offset > 0.05
    env.step(np.array([*gripper, 0, 0, 0, 0, P.FINGER_OPEN], np.float32))
    assert env.step(close_here)[4]["grasp_offset_m"] == info["grasp_offset_m"]  # the first close counts
    assert _demonstrate(env, 3)["grasp_offset_m"] < 0.01  # the demonstrator closes over the bar's centre


@pytest.mark.slow
def test_a_taken_place_is_a_collision_and_a_mat_of_the_other_grasp_is_no_success(env):
    taken = [True, True, True, True]
    info = _demonstrate(env, 0, {"orientation": "along_y", "taken": taken}, place=0)
    assert info["collision"] and not info["is_success"]
    info = _demonstrate(env, 0, {"orientation": "along_y", "taken": [False] * 4}, place=2)
    assert info["place"] == 2 and info["valid"] == [0, 1] and not info["is_success"] and not info["collision"]


def test_in_the_changed_condition_the_cup_moves_to_the_other_place_at_the_change_step():
    env = PickPlaceEnv(P.CHANGED)
    observation, info = env.reset(seed=1)
    before, step = info["valid"], info["change_step"]
    assert len(before) == 1 and P.CHANGE_STEPS[0] <= step <= P.CHANGE_STEPS[1]
    for _ in range(step + 1):
        observation, _, _, _, info = env.step(np.r_[observation[STATE_KEY][:7], P.FINGER_OPEN].astype(np.float32))
    assert len(info["valid"]) == 1 and info["valid"] != before
    env.close()
