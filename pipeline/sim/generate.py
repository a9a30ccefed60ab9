"""The simulator's demonstrations as a user's robot would write them: per demonstration a folder of PNG frames and a
pose CSV (`t,x,y,z,qx,qy,qz,qw,gripper`, seconds and metres), which `cnep ingest` takes as it takes a user's
(docs/how-to/own-csv-and-video.md).

The scripted demonstrator (cnep.sim.demonstrator) drives the environment itself: the frames and poses are what the
camera saw and the robot reported while it moved, not the plan. Sides are balanced: half the demonstrations pass
left, half right, in a seeded order (in the cue variant, the cue's side decides, drawn per demonstration).
`generate_pick_demonstrations` does the same for the pick-and-place task: each demonstration a scene drawn by the
environment (decided or free) and the place the demonstrator chose in it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cnep.outputs import temporary_path
from cnep.pipeline.progress import progress_bar
from cnep.runtime import STATE_KEY, STATE_NAMES
from cnep.sim import IMAGE_KEY, ObstacleEnv, PickPlaceEnv, demonstration_path, draw_demonstration, draw_pick, pick_path
from cnep.sim import scene as S
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.pick_place import scene as P

CSV_FILE = "poses.csv"
CSV_HEADER = ("t", *STATE_NAMES)
DEMO_SEED_OFFSET = 1_000_000  # demonstration starts are drawn from seeds above this; evaluation episodes from below


@dataclass(frozen=True)
class Generated:
    """folders: one per demonstration (sorted); sides: each one's side (pick and place: its place); successes: how
    many succeeded (reached the goal without touching the box; put the bar on a valid place)."""

    folders: list[Path]
    sides: list[str]
    successes: int


def generate_demonstrations(out: Path, n: int, seed: int, cue: bool = False, quiet: bool = False) -> Generated:
    """Write `n` demonstrations into out/demo_NNN/ (frames + CSV), seeded by `seed`."""
    rng = np.random.default_rng(seed)
    sides = [("left", "right")[i % 2] for i in range(n)]
    rng.shuffle(sides)
    env = ObstacleEnv(cue=cue, max_steps=O.DEMO_STEPS[1] + 1)
    folders, successes, taken = [], 0, []
    try:
        for i in progress_bar(range(n), desc="generate", unit="demo", quiet=quiet):
            options = {"cue_side": sides[i]} if cue else None
            observation, info = env.reset(seed=DEMO_SEED_OFFSET + seed * 10_000 + i, options=options)
            path = demonstration_path(draw_demonstration(rng, sides[i]), info["start"])
            steps = [observation]
            for waypoint in path:
                action = np.array([*waypoint, *observation[STATE_KEY][3:7], S.FINGER_OPEN], dtype=np.float32)
                observation, _, _, _, info = env.step(action)
                steps.append(observation)
            successes += bool(info["distance_to_goal"] < O.GOAL_TOLERANCE and not info["collision"])
            folder = out / f"demo_{i:03d}"
            _write(folder, steps, IMAGE_KEY)
            folders.append(folder)
            taken.append(sides[i])
    finally:
        env.close()
    return Generated(folders, taken, successes)


def generate_pick_demonstrations(out: Path, n: int, seed: int, quiet: bool = False) -> Generated:
    """Write `n` pick-and-place demonstrations into out/demo_NNN/ (frames + CSV), seeded by `seed`; `sides` holds
    each one's place (the pick-and-place scene's PLACES' name)."""
    rng = np.random.default_rng(seed)
    env = PickPlaceEnv()
    folders, successes, places = [], 0, []
    try:
        for i in progress_bar(range(n), desc="generate", unit="demo", quiet=quiet):
            observation, info = env.reset(seed=DEMO_SEED_OFFSET + seed * 10_000 + i)
            scene = env.scene
            draw = draw_pick(rng, scene["orientation"], scene["taken"])
            steps = [observation]
            for action in pick_path(draw, observation[STATE_KEY][:3], scene["object_xy"], scene["object_yaw"]):
                observation, _, _, _, info = env.step(action.astype(np.float32))
                steps.append(observation)
            successes += bool(info["is_success"])
            folder = out / f"demo_{i:03d}"
            _write(folder, steps, env.image_key)
            folders.append(folder)
            places.append(P.PLACES[draw.place][0])
    finally:
        env.close()
    return Generated(folders, places, successes)


def _write(folder: Path, steps: list[dict], image_key: str) -> None:
    """One demonstration's frames and CSV, written under a temporary name and renamed when complete."""
    work = temporary_path(folder)
    work.mkdir(parents=True)
    rows = []
    for k, observation in enumerate(steps):
        _, png = cv2.imencode(".png", cv2.cvtColor(observation[image_key], cv2.COLOR_RGB2BGR))
        (work / f"frame_{k:03d}.png").write_bytes(png.tobytes())
        rows.append([f"{k * S.CONTROL_PERIOD_S:.3f}", *(f"{v:.4f}" for v in observation[STATE_KEY])])
    lines = [",".join(CSV_HEADER), *(",".join(row) for row in rows)]
    (work / CSV_FILE).write_text("\n".join(lines) + "\n")
    work.rename(folder)
