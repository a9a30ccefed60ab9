"""The scripted demonstrators solve every kind of v1 scene over many seeds (the state alone, no frames rendered):
pick-and-place decided, free and changed during the carry, the obstacle passed on a drawn side and on the side of a
cue that shows after the start; and their phases' timing varies from demonstration to demonstration."""

import importlib.util

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.sim.paths import rollout  # noqa: E402
from cnep.sim.tasks.obstacle.demonstrator import draw_detour, obstacle_expert  # noqa: E402
from cnep.sim.tasks.obstacle.env import ObstacleEnv  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import draw_pick, pick_expert  # noqa: E402
from cnep.sim.tasks.pick_place.env import PickPlaceEnv  # noqa: E402

SEEDS = 10  # per kind of scene: the examples' demonstrators.py runs hundreds


@pytest.mark.slow
@pytest.mark.parametrize("condition", P.CONDITIONS)
def test_the_pick_and_place_demonstrator_solves_every_v1_scene(condition):
    env = PickPlaceEnv(condition, version=1, frames=False)
    for seed in range(SEEDS):
        _, info = env.reset(seed=seed)
        info, steps = rollout(env, pick_expert(env, info, np.random.default_rng(seed)).action, info)
        assert info["is_success"] and steps < env.max_steps, f"seed {seed}: {info}"
        assert (info["change_step"] is not None) == (condition == P.CHANGED)
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize("cue", [False, True])
def test_the_obstacle_demonstrator_solves_every_v1_scene(cue):
    env = ObstacleEnv(cue=cue, version=1, frames=False)
    for seed in range(SEEDS):
        _, info = env.reset(seed=seed)
        info, steps = rollout(env, obstacle_expert(env, np.random.default_rng(seed)).action, info)
        assert info["is_success"] and info["clearance"] > 0.03, f"seed {seed}: {info}"
        assert (info["cue_step"] is not None) == cue
    env.close()


def test_in_v1_each_phases_pace_is_drawn_apart():
    rng = np.random.default_rng(0)
    picks = np.array([draw_pick(rng, "along_y", [False] * 4, pace_per_phase=True).steps for _ in range(200)])
    detours = np.array([draw_detour(rng).steps for _ in range(200)])
    for steps in (picks, detours):
        ranks = steps.argsort(axis=0).argsort(axis=0)  # each phase's steps ranked over the draws
        correlation = np.corrcoef(ranks.T)[np.triu_indices(steps.shape[1], 1)]
        assert np.abs(correlation).max() < 0.3  # a quick phase says nothing of the others (v0: one pace for all)
    for phase, (lo, hi) in enumerate(P.PHASE_STEPS.values()):
        assert picks[:, phase].min() == lo and picks[:, phase].max() == hi
