"""The obstacle environment: Gymnasium's checker, the demonstrator clearing the box, physics-judged outcomes,
and closed-loop episodes by both protocols that the same seed repeats exactly and the step limit truncates."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import gymnasium  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from cnep.runtime import STATE_KEY  # noqa: E402
from cnep.sim import CUE_ENV_ID, ENV_ID, IMAGE_KEY, ObstacleEnv, demonstration_path, draw_demonstration  # noqa: E402
from cnep.sim import scene as S  # noqa: E402
from cnep.sim.episode import ONLINE, PLANNED, run_episode  # noqa: E402
from cnep.sim.tasks.obstacle import scene as O  # noqa: E402
from tests.sim.scripted import scripted_policy  # noqa: E402


@pytest.fixture(scope="module")
def env():
    env = ObstacleEnv()
    yield env
    env.close()


def test_the_environment_passes_gymnasiums_checker_and_is_registered():
    env = gymnasium.make(ENV_ID)
    check_env(env.unwrapped, skip_render_check=True)
    observation, _ = env.reset(seed=0)
    assert (
        observation[IMAGE_KEY].shape == (O.IMAGE_HEIGHT, O.IMAGE_WIDTH, 3) and observation[IMAGE_KEY].dtype == np.uint8
    )
    assert observation[STATE_KEY].shape == (8,)
    env.close()
    cue = gymnasium.make(CUE_ENV_ID).unwrapped
    sides = {cue.reset(seed=seed)[1]["cue_side"] for seed in range(8)}
    assert sides == {"left", "right"}
    cue.close()


@pytest.mark.slow
@pytest.mark.parametrize("side", ["left", "right"])
def test_the_scripted_demonstrator_reaches_the_goal_clear_of_the_box(env, side):
    rng = np.random.default_rng(1)
    for seed in range(3):
        observation, info = env.reset(seed=seed)
        for waypoint in demonstration_path(draw_demonstration(rng, side), info["start"]):
            action = np.array([*waypoint, 0, 0, 0, 1, S.FINGER_OPEN], np.float32)
            observation, _, terminated, _, info = env.step(action)
        assert info["is_success"] and not info["collision"]
        assert info["clearance"] > 0.05
        assert (observation[STATE_KEY][0] < 0) == (side == "left") or abs(observation[STATE_KEY][0]) < 0.03


def test_driving_through_the_box_is_a_collision_read_from_the_contacts(env):
    observation, info = env.reset(seed=0, options={"start": (0.0, O.START_Y)})
    action = observation[STATE_KEY].copy()
    for _ in range(30):
        action[1] += 0.02
        _, _, terminated, _, info = env.step(action)
        if terminated:
            break
    assert info["collision"] and not info["is_success"] and info["clearance"] < 0.001


@pytest.mark.parametrize("protocol", [PLANNED, ONLINE])
def test_a_closed_loop_episode_succeeds_and_the_same_seed_repeats_it_exactly(env, protocol):
    policy = scripted_policy(gate=(0.2, 0.8))
    first = run_episode(env, policy, seed=5, protocol=protocol)
    again = run_episode(env, policy, seed=5, protocol=protocol)
    other = run_episode(env, policy, seed=6, protocol=protocol)
    assert first.success and not first.collision and first.side == "right" and first.switches == 0
    assert len(first.gates) == (1 if protocol == PLANNED else len(first.states) - 1)
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.object_poses, again.object_poses)
    assert (first.clearance_m, first.distance_to_goal_m) == (again.clearance_m, again.distance_to_goal_m)
    assert not np.array_equal(first.states[0], other.states[0])  # another seed, another start


def test_with_the_split_option_episodes_take_both_sides_each_keeping_one_and_a_seed_repeats_its_side(env):
    policy = scripted_policy(gate=(0.5, 0.5), first_expert="sample")
    episodes = [run_episode(env, policy, seed=seed, protocol=ONLINE) for seed in range(6)]
    assert {ep.side for ep in episodes} == {"left", "right"}
    assert all(ep.switches == 0 and ep.success for ep in episodes)
    assert run_episode(env, policy, seed=3, protocol=ONLINE).side == episodes[3].side


def test_an_episode_run_with_its_frames_is_written_as_a_recording(env, tmp_path):
    from cnep.outputs import is_recorded, writing_as
    from cnep.pipeline.sim.rerun_log import write_episode
    from cnep.sim.tasks.obstacle.drawing import drawing

    ep = run_episode(env, scripted_policy(gate=(0.2, 0.8)), seed=5, protocol=ONLINE, record_frames=True)
    assert ep.frames is not None and len(ep.frames) == len(ep.states)
    with writing_as("sim eval"):
        path = write_episode(tmp_path / "episode.rrd", "episode", ep, 2, drawing(ep))
    assert path == tmp_path / "episode.rrd" and path.read_bytes()[:4] == b"RRF2"
    assert is_recorded(path, "sim eval")  # the command's output, named in its folder's record


def test_the_step_limit_truncates_every_episode_and_leaves_the_plan_spanning_the_task(monkeypatch):
    import cnep.pipeline.sim.loop as loop
    from cnep.pipeline.sim.config import LoopSettings
    from cnep.sim.tasks import find_task

    opened = []

    def open_scripted(path: Path, *, waypoints: int, **kwargs) -> object:
        opened.append(waypoints)
        return scripted_policy(gate=(0.2, 0.8), waypoints=waypoints)

    monkeypatch.setattr(loop, "open_policy", open_scripted)
    task, settings = find_task("obstacle", 0), LoopSettings(episodes=2, max_steps=7)
    results = loop.evaluate_policy(loop.open_task_policy(Path("scripted"), task), task, settings, label="s")
    assert opened == [O.MAX_STEPS]  # the plan: the task's steps, not the limit's
    assert list(results) == [PLANNED, ONLINE]
    for rates in results.values():
        assert [(row["steps"], row["success"]) for row in rates["per_episode"]] == [(7, False), (7, False)]
