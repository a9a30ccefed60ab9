"""The scripted demonstrator of the obstacle task: start to goal past the box on one side, with natural variation.

A demonstration (`DemoDraw`, drawn by `draw_demonstration` from a generator) has a side, a number of steps (its
speed), the detour's lateral reach at the box and the shape of the bump (scene.DEMO_STEPS, DETOUR, DETOUR_SHAPE,
DETOUR_PEAK). Its path (`demonstration_path`) runs from the start to the goal with a minimum-jerk timing; the lateral
offset is a bump that reaches the detour at the peak's progress: x = start_x (1 - s) + sign * detour * bump(s).
`demonstrations` drives the environment with them, as a robot records a demonstration.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from cnep.runtime import STATE_KEY
from cnep.sim import scene as S
from cnep.sim.task import Demonstration, demonstration_seed, recorded
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.env import ObstacleEnv


@dataclass(frozen=True)
class DemoDraw:
    """One demonstration's choices: side ("left" / "right"), steps (control steps from start to goal), detour (m),
    shape (the bump's exponent), peak (the progress in (0, 1) where the detour is widest)."""

    side: str
    steps: int
    detour: float
    shape: float
    peak: float


def draw_demonstration(rng: np.random.Generator, side: str | None = None) -> DemoDraw:
    """A demonstration's choices drawn from `rng`; `side` None: left or right with equal chance."""
    side = side if side is not None else ("left", "right")[int(rng.integers(2))]
    lo, hi = O.DEMO_STEPS
    return DemoDraw(
        side=side,
        steps=int(rng.integers(lo, hi + 1)),
        detour=float(rng.uniform(*O.DETOUR)),
        shape=float(rng.uniform(*O.DETOUR_SHAPE)),
        peak=float(rng.uniform(*O.DETOUR_PEAK)),
    )


def demonstration_path(draw: DemoDraw, start: np.ndarray) -> np.ndarray:
    """The waypoints (draw.steps, 3) in m after `start` (x, y): waypoint k is where the end effector goes at step
    k + 1; the last is the goal."""
    tau = np.arange(1, draw.steps + 1) / draw.steps
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5  # minimum-jerk progress, 0 -> 1
    warped = np.where(s < draw.peak, 0.5 * s / draw.peak, 0.5 + 0.5 * (s - draw.peak) / (1 - draw.peak))
    bump = np.sin(np.pi * warped) ** draw.shape  # 0 at the ends, 1 at the peak
    x = start[0] * (1 - s) + O.GOAL_XY[0] * s + O.SIDE_SIGN[draw.side] * draw.detour * bump
    y = start[1] * (1 - s) + O.GOAL_XY[1] * s
    return np.stack([x, y, np.full_like(x, O.EE_HEIGHT)], axis=1)


def demonstrations(n: int, seed: int, cue: bool = False) -> Iterator[Demonstration]:
    """`n` demonstrations drawn with `seed`, each driving the environment from its own reset: half pass left, half
    right, in a seeded order (in the cue variant the cue shows the side); clean when it reached the goal clear of the
    box."""
    rng = np.random.default_rng(seed)
    sides = [O.SIDES[i % 2] for i in range(n)]
    rng.shuffle(sides)
    env = ObstacleEnv(cue=cue, max_steps=O.DEMO_STEPS[1] + 1)
    try:
        for i, side in enumerate(sides):
            observation, info = env.reset(seed=demonstration_seed(seed, i), options={"cue_side": side} if cue else None)
            steps = [observation]
            for waypoint in demonstration_path(draw_demonstration(rng, side), info["start"]):
                action = np.array([*waypoint, *observation[STATE_KEY][3:7], S.FINGER_OPEN], dtype=np.float32)
                observation, _, _, _, info = env.step(action)
                steps.append(observation)
            clean = bool(info["distance_to_goal"] < O.GOAL_TOLERANCE and not info["collision"])
            yield recorded(steps, env.image_key, side, clean)
    finally:
        env.close()
