"""A task as the closed loop runs it: one `Task` per folder of sim/tasks, which the pipeline's one stage, loop, summary
and evaluation read, and the demonstrations its scripted demonstrator makes.

    from cnep.sim.tasks import find_task
    task = find_task("pick-place", 1)                    # the task on its environment's version 1
    env = task.make_env("changed", task.max_steps)      # a condition, the episode's steps, the task's variants
    for demo in task.demonstrations(40, seed=0):        # frames and states as the robot sensed them
        ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from cnep.runtime import STATE_KEY
from cnep.sim.drawing import Drawing
from cnep.sim.episode import EpisodeResult
from cnep.sim.scoring import Column
from cnep.sim.tabletop import TabletopEnv

DEMO_SEED_OFFSET = 1_000_000  # demonstrations reset with seeds above this; evaluation episodes with seeds below


def demonstration_seed(seed: int, i: int) -> int:
    """The reset seed of demonstration `i` of the set drawn with `seed`: never an evaluation episode's."""
    return DEMO_SEED_OFFSET + seed * 10_000 + i


@dataclass(frozen=True)
class Demonstration:
    """One scripted demonstration as the robot recorded it: frames (T, H, W, 3) uint8 and states (T, 8) float32, one
    per control step from the reset on; behaviour, what it did (a Task.behaviours entry: the side it passed, the
    place it chose); clean, whether it succeeded."""

    frames: np.ndarray
    states: np.ndarray
    behaviour: str
    clean: bool


def recorded(observations: list[dict], image_key: str, behaviour: str, clean: bool) -> Demonstration:
    """A demonstration of the environment's `observations` (its camera under `image_key`)."""
    frames = np.stack([observation[image_key] for observation in observations])
    return Demonstration(frames, np.stack([observation[STATE_KEY] for observation in observations]), behaviour, clean)


@dataclass(frozen=True)
class Task:
    """A closed-loop task.

    name: as `cnep sim NAME` and `--task` take it; version: the version of its environment it runs (0: the
    teleporting gripper; 1: a robot's constraints and a change during the motion; the task folder's versions.py);
    env_id: its Gymnasium id (of that version); max_steps: an episode's control steps (the version's; the planned
    protocol's plan spans them); conditions: the scene conditions an evaluation runs in turn (an
    episode's `condition`; none: the environment's own scenes, and the results are not split by condition);
    variants: the boolean options its environment and demonstrator take (the obstacle's `cue`); behaviours: what
    a demonstration can do (Demonstration.behaviour).
    make_env(condition, max_steps, **variants): an environment of the version (closed by the caller);
    demonstrations(n, seed, **variants): `n` seeded demonstrations (Demonstration) of the version's scripted
    demonstrator, each from its own reset (demonstration_seed);
    describe_demonstrations(behaviours): what the summary says of a set's behaviours; row(episode) and
    rates(rows): an episode's JSON-able row and the rates of one policy's rows under one protocol and condition;
    columns: the table's columns over those rates; drawing(episode): how its recordings and figure draw it.
    """

    name: str
    version: int
    env_id: str
    max_steps: int
    conditions: tuple[str, ...]
    variants: tuple[str, ...]
    behaviours: tuple[str, ...]
    make_env: Callable[..., TabletopEnv]
    demonstrations: Callable[..., Iterator[Demonstration]]
    describe_demonstrations: Callable[[list[str]], dict]
    row: Callable[[EpisodeResult], dict]
    rates: Callable[[list[dict]], dict]
    columns: tuple[Column, ...]
    drawing: Callable[[EpisodeResult], Drawing]
