"""The environments' versions: v0 exactly as its results were measured (seeded episodes digested before v1 existed),
v1 registered beside it and passing Gymnasium's checker, an action's latency, the robot's sensing drawn from the
seed, the grip's margin, and the changes during the motion: the cup during the carry, the cue after the start."""

import hashlib
import importlib.util
import json
from dataclasses import replace

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import gymnasium  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from cnep.runtime import STATE_KEY  # noqa: E402
from cnep.sim import (  # noqa: E402
    CUE_ENV_ID,
    CUE_ENV_V1_ID,
    ENV_ID,
    ENV_V1_ID,
    PICK_ENV_ID,
    PICK_ENV_V1_ID,
    ObstacleEnv,
    PickPlaceEnv,
    demonstration_path,
    draw_demonstration,
    draw_pick,
    pick_path,
)
from cnep.sim import scene as S  # noqa: E402
from cnep.sim.paths import rollout  # noqa: E402
from cnep.sim.tasks.obstacle import scene as O  # noqa: E402
from cnep.sim.tasks.obstacle.demonstrator import obstacle_expert  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place import versions  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import pick_expert  # noqa: E402
from cnep.sim.tasks.pick_place.versions import V0, V1, grip_margin  # noqa: E402

# The info keys v0 had, and the digests of v0 episodes (each seed's scripted demonstration) taken before v1 existed:
# the states, rewards, ends and these infos (floats to 1e-6) of every step. The frames were compared alike, once,
# on the machine that took these (they depend on the renderer).
V0_INFO_KEYS = {
    "obstacle": ("is_success", "collision", "clearance", "distance_to_goal", "cue_side"),
    "pick": ("is_success", "lifted", "dropped", "collision", "released", "at_rest", "place", "valid", "condition",
             "orientation", "taken", "change_step"),
}  # fmt: skip
V0_DIGESTS = [
    (ENV_ID, {}, 0, "4451aa3f452852c0"),
    (CUE_ENV_ID, {}, 1, "3d5c91b28ba1f6bd"),
    (PICK_ENV_ID, {}, 0, "205cba43001342ed"),
    (PICK_ENV_ID, {"condition": P.CHANGED}, 1, "38967c1440812475"),
]


def _v0_digest(env_id: str, seed: int, **kwargs) -> str:
    """The digest of a v0 episode reset with `seed` and driven by the scripted demonstrator (V0_DIGESTS)."""
    env = gymnasium.make(env_id, frames=False, **kwargs).unwrapped
    keys = V0_INFO_KEYS["pick" if env_id == PICK_ENV_ID else "obstacle"]
    digest = hashlib.sha256()

    def keep(observation: dict, info: dict, *rest) -> None:
        digest.update(observation[STATE_KEY].tobytes())
        values = {k: round(v, 6) if isinstance(v, float) else v for k, v in info.items() if k in keys}
        digest.update(json.dumps([values, *rest], sort_keys=True, default=str).encode())

    observation, info = env.reset(seed=seed)
    keep(observation, info)
    if env_id == PICK_ENV_ID:
        draw = draw_pick(np.random.default_rng(seed), env.scene["orientation"], env.scene["taken"])
        path = pick_path(draw, observation[STATE_KEY][:3], env.scene["object_xy"], env.scene["object_yaw"])
    else:
        waypoints = demonstration_path(draw_demonstration(np.random.default_rng(seed)), info["start"])
        path = [np.array([*w, 0, 0, 0, 1, S.FINGER_OPEN]) for w in waypoints]
    for action in path:
        observation, reward, terminated, truncated, info = env.step(np.asarray(action, np.float32))
        keep(observation, info, reward, terminated, truncated)
        if terminated or truncated:
            break
    env.close()
    return digest.hexdigest()[:16]


@pytest.mark.parametrize(("env_id", "kwargs", "seed", "expected"), V0_DIGESTS)
def test_a_seeded_v0_episode_is_the_one_measured_before_v1_existed(env_id, kwargs, seed, expected):
    assert _v0_digest(env_id, seed, **kwargs) == expected


@pytest.mark.parametrize("env_id", [ENV_V1_ID, CUE_ENV_V1_ID, PICK_ENV_V1_ID])
def test_the_v1_environments_are_registered_and_pass_gymnasiums_checker(env_id):
    env = gymnasium.make(env_id, max_steps=10)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.unwrapped.version.robot.max_speed is not None
    env.close()
    stateless = gymnasium.make(env_id, max_steps=10, frames=False).unwrapped  # no camera: the state alone
    check_env(stateless, skip_render_check=True)
    assert list(stateless.observation_space) == [STATE_KEY] and stateless.camera is None
    stateless.close()


def test_the_same_seed_draws_the_same_v1_episode_and_another_seed_another_camera_light_and_noise():
    env = PickPlaceEnv(version=1)
    first, _ = env.reset(seed=3)
    camera = (env.model.cam_pos[0].copy(), env.model.vis.headlight.diffuse.copy())
    again, _ = env.reset(seed=3)
    np.testing.assert_array_equal(first[env.image_key], again[env.image_key])
    np.testing.assert_array_equal(first[STATE_KEY], again[STATE_KEY])
    other, _ = env.reset(seed=4)
    assert not np.array_equal(env.model.cam_pos[0], camera[0])
    assert not np.array_equal(env.model.vis.headlight.diffuse, camera[1])
    still = np.r_[other[STATE_KEY][:7], P.FINGER_OPEN].astype(np.float32)
    states = [env.step(still)[0][STATE_KEY] for _ in range(3)]
    assert len({tuple(s[:3]) for s in states}) == 3  # the same pose reported with fresh noise each step
    assert np.abs(np.diff(states, axis=0)[:, :3]).max() < 0.02
    env.close()


def test_with_latency_each_action_acts_a_step_late():
    moves = {}
    for latency in (0, 1):
        env = ObstacleEnv(version=1, latency_steps=latency, frames=False)
        observation, info = env.reset(seed=0)
        target = np.array([*info["start"] + [0.0, 0.05], O.EE_HEIGHT, 0, 0, 0, 1, S.FINGER_OPEN], np.float32)
        ys = []
        for _ in range(3):
            env.step(target)
            ys.append(env.data.body(S.GRIPPER_BODY).xpos[1])  # where it is (the state is noisy)
        moves[latency] = np.array(ys) - info["start"][1]
        env.close()
    # From rest, the arm's acceleration covers about 6 mm in a control period.
    assert moves[0][0] > 0.002 and abs(moves[1][0]) < 0.0005  # held where the reset put it for one step
    np.testing.assert_allclose(moves[1][1:], moves[0][:-1], atol=1e-4)
    with pytest.raises(ValueError, match="latency_steps"):
        ObstacleEnv(latency_steps=-1, frames=False)


def test_the_v1_grip_holds_a_few_times_the_bars_weight_where_v0s_held_28_and_the_physics_agrees(monkeypatch):
    assert 3.0 < grip_margin(V1) <= 5.0
    assert 28.0 < grip_margin(V0) < 29.0
    with pytest.raises(ValueError, match="versions 0 to 1"):
        PickPlaceEnv(version=2)
    lifted = {}
    for margin in (1.3, 0.9):  # the bar made heavier until the grip holds 1.3, then 0.9 times its weight
        heavy = replace(V1, object_mass=V1.object_mass * grip_margin(V1) / margin)
        monkeypatch.setattr(versions, "VERSIONS", (V0, heavy))
        env = PickPlaceEnv(P.DECIDED, version=1, frames=False)
        _, info = env.reset(seed=1)
        info, _ = rollout(env, pick_expert(env, info, np.random.default_rng(1)).action, info)
        lifted[margin] = info["lifted"] and info["is_success"]
        env.close()
    assert lifted == {1.3: True, 0.9: False}  # the friction holds the bar, up to its margin


def test_in_v1_the_cup_moves_during_the_carry_towards_it_and_the_info_records_what_was_valid_after():
    env = PickPlaceEnv(P.CHANGED, version=1, frames=False)
    _, info = env.reset(seed=2)
    before, share = info["valid"], env.scene["change_share"]
    assert info["change_step"] is None and info["valid_after_change"] is None and len(before) == 1
    expert = pick_expert(env, info, np.random.default_rng(2))
    infos = [info]
    while infos[-1]["change_step"] is None and len(infos) <= env.max_steps:
        infos.append(env.step(expert.action(infos[-1]))[4])
    change = infos[-1]["change_step"]
    assert change is not None and change == len(infos) - 2  # changed before the last step's action acted
    assert infos[change]["lifted"] and infos[change]["valid"] != infos[-1]["valid"]
    assert infos[-1]["valid_after_change"] == infos[-1]["valid"] != before
    assert infos[-1]["taken"][before[0]]  # the cup stands where the gripper was heading
    assert V1.change_share[0] <= share <= V1.change_share[1]
    env.close()


def test_in_v1_the_cup_stays_while_the_gripper_does_not_head_for_its_place():
    env = PickPlaceEnv(P.CHANGED, version=1, frames=False)
    observation, info = env.reset(seed=2)
    still = np.r_[info["start"], V1.start[2], 0, 0, 0, 1, P.FINGER_OPEN].astype(np.float32)
    for _ in range(15):
        info = env.step(still)[4]
    assert info["change_step"] is None and not info["lifted"]
    env.close()


def test_in_v1_the_cue_shows_once_the_gripper_has_moved_or_at_the_latest_step():
    env = ObstacleEnv(cue=True, version=1, frames=False)
    cue = env.model.geom(O.CUE_GEOM).id
    _, info = env.reset(seed=0)
    assert info["cue_step"] is None and env.model.geom_pos[cue][2] < 0  # hidden at the start
    expert = obstacle_expert(env, np.random.default_rng(0))
    while info["cue_step"] is None:
        info = env.step(expert.action(info))[4]
    (box_x, _), shown = env.scene["box_xy"], env.model.geom_pos[cue]
    assert 0 < info["cue_step"] <= env.version.cue_latest_step and shown[2] > 0
    assert (shown[0] < box_x) == (info["cue_side"] == "left")
    _, info = env.reset(seed=0)
    still = np.r_[info["start"], O.EE_HEIGHT, 0, 0, 0, 1, S.FINGER_OPEN].astype(np.float32)
    steps = [env.step(still)[4]["cue_step"] for _ in range(env.version.cue_latest_step + 1)]
    assert steps[-2] is None and steps[-1] == env.version.cue_latest_step  # a gripper that waits sees it too
    env.close()
    v0 = ObstacleEnv(cue=True, frames=False)
    assert v0.reset(seed=0)[1]["cue_step"] == 0  # v0 shows it from the start
    v0.close()


@pytest.mark.slow
def test_the_v1_demonstrators_still_solve_scenes_of_every_kind_with_an_actions_latency():
    for env, expert in (
        (PickPlaceEnv(P.CHANGED, version=1, latency_steps=1, frames=False), pick_expert),
        (ObstacleEnv(cue=True, version=1, latency_steps=1, frames=False), None),
    ):
        for seed in range(2):
            _, info = env.reset(seed=seed)
            rng = np.random.default_rng(seed)
            act = expert(env, info, rng) if expert else obstacle_expert(env, rng)
            info, _ = rollout(env, act.action, info)
            assert info["is_success"]
        env.close()
