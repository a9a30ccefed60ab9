"""Do the scripted demonstrators solve every scene? Their success over many seeds, per environment version and kind
of scene, each demonstrator in closed loop (pick_expert, obstacle_expert), on the state alone (no frames rendered).

    python examples/demonstrators.py [--seeds N] [--versions 0,1] [--latency-steps K]

Scenes: pick-and-place `decided`, `free` and `changed` (v0: the cup moves at a drawn step before the grasp; v1:
during the carry), the obstacle `free` (the side the demonstrator's) and `cue` (v0: the cue from the start; v1:
shown during the motion). Prints one row per version and scene: the episodes (seeds 0 to N - 1), the successes, the
episodes in which the scene changed during the motion, and the steps an episode took (min, median, max).
"""

from __future__ import annotations

import argparse

import numpy as np

from cnep.sim.paths import rollout
from cnep.sim.tasks.obstacle.demonstrator import obstacle_expert
from cnep.sim.tasks.obstacle.env import ObstacleEnv
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.demonstrator import pick_expert
from cnep.sim.tasks.pick_place.env import PickPlaceEnv

SCENES = [("pick-place", condition) for condition in P.CONDITIONS] + [("obstacle", "free"), ("obstacle", "cue")]


def sweep(task: str, scene: str, version: int, seeds: int, latency_steps: int) -> dict:
    """The demonstrator of `task` in `scene` (SCENES) of `version` over `seeds` seeds: a row (module docstring)."""
    if task == "pick-place":
        env = PickPlaceEnv(scene, version=version, latency_steps=latency_steps, frames=False)
    else:
        env = ObstacleEnv(cue=scene == "cue", version=version, latency_steps=latency_steps, frames=False)
    successes, changed, steps = 0, 0, []
    for seed in range(seeds):
        _, info = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        expert = pick_expert(env, info, rng) if task == "pick-place" else obstacle_expert(env, rng)
        info, taken = rollout(env, expert.action, info)
        successes += bool(info["is_success"])
        change = info.get("change_step", info.get("cue_step"))
        changed += change is not None and change > 0  # v0's cue, shown at the reset, changes nothing
        steps.append(taken)
    env.close()
    low, median, high = np.percentile(steps, [0, 50, 100])
    return {"task": task, "scene": scene, "version": version, "episodes": seeds, "success": successes,
            "changed": changed, "steps": (int(low), float(median), int(high))}  # fmt: skip


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=200, help="episodes per version and scene (seeds 0 to N - 1)")
    parser.add_argument("--versions", default="0,1", help="the environments' versions, comma-separated")
    parser.add_argument("--latency-steps", type=int, default=0, help="control steps each action acts late")
    args = parser.parse_args(argv)
    rows = []
    print("| task | scene | version | episodes | success | changed | steps (min / median / max) |")
    print("|---|---|---|---|---|---|---|")
    for version in (int(v) for v in args.versions.split(",")):
        for task, scene in SCENES:
            row = sweep(task, scene, version, args.seeds, args.latency_steps)
            low, median, high = row["steps"]
            print(f"| {task} | {scene} | v{version} | {row['episodes']} | {row['success']} | {row['changed']} | "
                  f"{low} / {median:g} / {high} |", flush=True)  # fmt: skip
            rows.append(row)
    return rows


if __name__ == "__main__":
    main()
