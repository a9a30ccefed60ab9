"""The built-in demonstration set: seeded synthetic tabletop demonstrations written as demonstration MCAP files.

Each demonstration is what a robot recorder would store (through `recordings`): the camera frames
(pipeline.demo.scene), the end-effector pose (xyz in m + quaternion xyzw) and the gripper opening (m) at
`fps` Hz. The scene decides the behaviour (pipeline.demo.scene.BEHAVIOURS); the motion is a minimum-jerk
path through waypoints: home -> above the cup -> down -> close -> lift -> above the free slot -> down
-> open -> lift. All behaviours start at the same home pose, two behaviours share each grasp and each
place point, and the paths cross in the table plane. Phase durations and waypoints vary per
demonstration.

The behaviour label is kept in the episode's `extra` metadata (`behaviour`) for the demo's summary
only: file names do not reveal it and training reads trajectories, never this key.

A scene-change episode starts as one behaviour; when the cup has been lifted, the block is moved to
the other slot, the scene now calls for the other behaviour and the demonstrator places the cup there.

A free-choice episode shows a tray with both slots free (pipeline.demo.scene.FREE_CHOICE): both places
are right and the demonstrator picks one at random (from the episode's seeded generator). Its label is
the scene (`left-either`, `right-either`) and, in `choice`, the slot picked; like the behaviour label,
both are for the summary only. Training sets mix them among the scene-decided demonstrations; the
`free_choice` split holds held-out free-choice scenes.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.outputs import output_file, writing_as
from cnep.pipeline.demo.scene import (
    BEHAVIOURS,
    FREE_CHOICE,
    SIDES,
    Scene,
    behaviour_parts,
    draw_frame,
    encode_jpeg,
    gripper_quaternion,
    sample_scene,
)
from cnep.pipeline.inputs import coerce_paths
from cnep.pipeline.progress import progress_bar
from cnep.recordings import Demonstration, Episode, write_demonstration

log = logging.getLogger(__name__)

TASK = "tabletop: put the cup into the free slot"
SOURCE = "cnep.pipeline.demo.generator"
LABEL_KEY = "behaviour"  # episode extra metadata: the behaviour name (summary only, never a training input)
SWITCH_KEY = "switch_step"  # scene-change episodes: the first step showing the changed scene
CHOICE_KEY = "choice"  # free-choice episodes: the slot the demonstrator picked (summary only)
CHOICE_STEP_KEY = "choice_step"  # free-choice episodes: the first step of the carry (the paths part there)

HOME = (0.0, 0.36, 0.30)  # m
HOVER_Z = 0.16  # height above the cup / slot before going down (m)
GRASP_Z = 0.04
PLACE_Z = 0.06
CARRY_Z = 0.18
GRIPPER_OPEN = 0.08  # opening (m) when open; the recorded gripper value is opening x GRIPPER_OPEN
HOLD_OPENING = 0.35  # fraction of GRIPPER_OPEN while holding the cup
GRASP_YAW = {"left": 0.6, "right": -0.6}  # rad: the cup is approached from the side it stands on
PLACE_YAW = {"near": -0.25, "far": 0.25}
# Phases (name, nominal share of the episode); the lift ends at the scene-change point.
PHASES = (
    ("reach", 0.18),
    ("descend", 0.08),
    ("close", 0.07),
    ("lift", 0.09),
    ("carry", 0.22),
    ("lower", 0.08),
    ("open", 0.07),
    ("retreat", 0.11),
)
TIMING_JITTER = 0.15  # relative std of each phase's duration
WAYPOINT_NOISE = 0.006  # std of each waypoint's xyz offset (m): demonstrator variability
SPLITS = ("train", "heldout", "scene_change", "free_choice")
SLOTS = ("near", "far")


@dataclass(frozen=True)
class Plan:
    """Waypoint states (x, y, z, yaw, opening) at their steps; the motion between them is minimum-jerk."""

    steps: np.ndarray  # (P + 1,) int, increasing, first 0 and last T - 1
    states: np.ndarray  # (P + 1, 5)

    def at(self, T: int) -> np.ndarray:
        """The state at every step: (T, 5)."""
        out = np.empty((T, self.states.shape[1]))
        for i in range(len(self.steps) - 1):
            a, b = self.steps[i], self.steps[i + 1]
            s = (np.arange(a, b + 1) - a) / max(1, b - a)
            blend = 10 * s**3 - 15 * s**4 + 6 * s**5  # minimum jerk, 0 -> 1 with zero velocity at both ends
            out[a : b + 1] = self.states[i] + blend[:, None] * (self.states[i + 1] - self.states[i])
        return out


def phase_steps(T: int, rng: np.random.Generator) -> np.ndarray:
    """Boundaries of the phases (len(PHASES) + 1,) in steps, with jittered durations."""
    shares = np.array([share for _, share in PHASES]) * np.exp(rng.normal(0.0, TIMING_JITTER, len(PHASES)))
    bounds = np.round(np.concatenate([[0.0], np.cumsum(shares) / shares.sum()]) * (T - 1)).astype(int)
    return np.maximum.accumulate(bounds)


def plan_motion(scene: Scene, slot: str, steps: np.ndarray, rng: np.random.Generator) -> Plan:
    """Waypoints of the demonstration that grasps the cup of `scene` and places it into `slot`."""
    side, _ = behaviour_parts(scene.behaviour)
    cup, target = scene.cup_xy, scene.slot_xy[slot]
    g, p = GRASP_YAW[side], PLACE_YAW[slot]
    states = np.array(
        [
            [*HOME, 0.0, 1.0],
            [*cup, HOVER_Z, g, 1.0],  # reach: above the cup
            [*cup, GRASP_Z, g, 1.0],  # descend
            [*cup, GRASP_Z, g, HOLD_OPENING],  # close
            [*cup, CARRY_Z, g, HOLD_OPENING],  # lift
            [*target, CARRY_Z, p, HOLD_OPENING],  # carry
            [*target, PLACE_Z, p, HOLD_OPENING],  # lower
            [*target, PLACE_Z, p, 1.0],  # open
            [*target, CARRY_Z, p, 1.0],  # retreat
        ]
    )
    states[1:, :3] += rng.normal(0.0, WAYPOINT_NOISE, (len(states) - 1, 3))
    states[2:4, :3] = states[2, :3]  # the fingers close where they went down
    states[6:8, :3] = states[6, :3]  # and open where they went down
    return Plan(steps, states)


def render(
    scenes: Sequence[Scene],
    switch: int,
    plan: Plan,
    fps: float,
    rng: np.random.Generator,
    episode: Episode,
    rendered: int | None = None,
) -> Demonstration:
    """Frames, pose and gripper of a planned demonstration; frames before step `switch` show scenes[0], then
    scenes[-1]. `rendered`: only the first this many steps (None: every step); the frames draw their sensor
    noise in step order, so these equal the whole demonstration's first frames."""
    T = int(plan.steps[-1]) + 1
    n = T if rendered is None else min(rendered, T)
    whole = plan.at(T)  # (T, 5)
    states = whole[:n]  # (n, 5)
    pose = np.concatenate([states[:, :3], np.stack([gripper_quaternion(y) for y in states[:, 3]])], axis=1)
    grasped, released = plan.steps[3], plan.steps[7]  # end of "close", end of "open"
    place_xy = whole[released, :2]
    frames = []
    for k in range(n):
        scene = scenes[0] if k < switch else scenes[-1]
        cup_xy = scene.cup_xy if k < grasped else None if k < released else place_xy
        frames.append(encode_jpeg(draw_frame(scene, pose[k], states[k, 4], cup_xy, rng)))
    timestamps = np.round(np.arange(n) * 1e9 / fps).astype(np.int64)
    return Demonstration(episode, timestamps, pose, states[:, 4] * GRIPPER_OPEN, frames)


def make_demonstration(
    behaviour: int, steps: int, fps: float, rng: np.random.Generator, episode_id: str, rendered: int | None = None
) -> Demonstration:
    """One demonstration of `behaviour` (index into BEHAVIOURS) with `steps` steps at `fps` Hz; `rendered`: only
    its first this many steps (`render`), e.g. 1 for a scene's first frame at a fraction of the cost."""
    scene = sample_scene(behaviour, rng)
    plan = plan_motion(scene, scene.free_slot, phase_steps(steps, rng), rng)
    episode = Episode(episode_id, fps, TASK, SOURCE, {LABEL_KEY: BEHAVIOURS[behaviour]})
    return render([scene], steps, plan, fps, rng, episode, rendered)


def make_scene_change(
    behaviour: int, steps: int, fps: float, rng: np.random.Generator, episode_id: str
) -> Demonstration:
    """A demonstration that starts as `behaviour`; once the cup is lifted, the block moves to the other slot.

    From that step on the frames show the changed scene and the demonstrator places the cup into the
    slot that became free (the other behaviour with the same cup side).
    """
    before = sample_scene(behaviour, rng)
    side, slot = behaviour_parts(behaviour)
    other = BEHAVIOURS.index(f"{side}-{'far' if slot == 'near' else 'near'}")
    after = Scene(other, before.cup_xy, before.slot_xy, before.clutter, before.gain, before.gradient)
    bounds = phase_steps(steps, rng)
    switch = int(bounds[4])  # end of the lift: both plans agree up to here
    plan = plan_motion(after, after.free_slot, bounds, rng)
    extra = {LABEL_KEY: f"{BEHAVIOURS[behaviour]}->{BEHAVIOURS[other]}", SWITCH_KEY: str(switch)}
    episode = Episode(episode_id, fps, TASK, SOURCE, extra)
    return render([before, after], switch, plan, fps, rng, episode)


def make_free_choice(side: str, steps: int, fps: float, rng: np.random.Generator, episode_id: str) -> Demonstration:
    """One demonstration in a scene with both slots free: the cup on `side`, the slot picked at random by `rng`."""
    slot = SLOTS[int(rng.integers(len(SLOTS)))]
    scene = sample_scene(BEHAVIOURS.index(f"{side}-{slot}"), rng, both_free=True)
    bounds = phase_steps(steps, rng)
    plan = plan_motion(scene, slot, bounds, rng)
    extra = {LABEL_KEY: FREE_CHOICE[SIDES.index(side)], CHOICE_KEY: slot, CHOICE_STEP_KEY: str(int(bounds[4]))}
    return render([scene], steps, plan, fps, rng, Episode(episode_id, fps, TASK, SOURCE, extra))


@dataclass(frozen=True)
class DemoSetConfig:
    """What to generate: `per_behaviour` training and `heldout_per_behaviour` held-out demonstrations of each
    behaviour, plus `scene_changes` scene-change episodes, `free_choice_per_side` training and
    `heldout_free_choice_per_side` held-out free-choice episodes per cup side, each `steps` steps at `fps` Hz,
    all from `seed`."""

    out: Path
    per_behaviour: int = 12
    heldout_per_behaviour: int = 3
    scene_changes: int = 1
    steps: int = 60
    fps: float = 10.0
    seed: int = 0
    quiet: bool = False
    free_choice_per_side: int = 0
    heldout_free_choice_per_side: int = 0

    def __post_init__(self) -> None:
        coerce_paths(self)


@dataclass(frozen=True)
class DemoSet:
    """Files written, per split (`train`, `heldout`, `scene_change`, `free_choice`), and each file's label
    (a behaviour name, `a->b` for a scene change, `<side>-either` for a free choice)."""

    files: dict[str, list[Path]]
    labels: dict[Path, str]


@writing_as("demo")  # the demo's recordings, also when generated on their own
def generate(config: DemoSetConfig) -> DemoSet:
    """Write the demonstration set under `config.out/<split>/demo_NNN.mcap`; returns the files and labels.

    Every episode has its own generator spawned from `config.seed`, so a set is reproducible file by
    file. Episode kinds (behaviours, free-choice sides) are shuffled over the file numbers so names carry
    no label.
    """
    if config.steps < 2 * len(PHASES):
        raise ValueError(f"steps must be >= {2 * len(PHASES)} (two per motion phase), got {config.steps}")
    K = len(BEHAVIOURS)
    kinds = {  # per split, the kind of each episode before shuffling: 0..K-1 a behaviour, K + s free choice on side s
        "train": [
            *np.arange(config.per_behaviour * K) % K,
            *(K + np.arange(config.free_choice_per_side * len(SIDES)) % len(SIDES)),
        ],
        "heldout": [*np.arange(config.heldout_per_behaviour * K) % K],
        "scene_change": [*np.arange(config.scene_changes) % K],
        "free_choice": [*(K + np.arange(config.heldout_free_choice_per_side * len(SIDES)) % len(SIDES))],
    }
    root = np.random.SeedSequence(config.seed)
    split_seeds = dict(zip(SPLITS, root.spawn(len(SPLITS))))
    files: dict[str, list[Path]] = {split: [] for split in SPLITS}
    labels: dict[Path, str] = {}
    with progress_bar(total=sum(map(len, kinds.values())), desc="generate", unit="demo", quiet=config.quiet) as bar:
        for split in SPLITS:
            n = len(kinds[split])
            shuffle = np.random.default_rng(split_seeds[split].spawn(1)[0]).permutation(n)
            order = np.asarray(kinds[split], dtype=int)[shuffle]
            for i, (kind, seq) in enumerate(zip(order, split_seeds[split].spawn(n))):
                rng = np.random.default_rng(seq)
                episode_id = f"{split}/demo_{i:03d}"
                if kind >= K:
                    demo = make_free_choice(SIDES[kind - K], config.steps, config.fps, rng, episode_id)
                else:
                    make = make_scene_change if split == "scene_change" else make_demonstration
                    demo = make(int(kind), config.steps, config.fps, rng, episode_id)
                path = Path(config.out) / f"{episode_id}.mcap"
                path.parent.mkdir(parents=True, exist_ok=True)
                with output_file(path) as staged:
                    write_demonstration(staged, demo)
                files[split].append(path)
                labels[path] = demo.episode.extra[LABEL_KEY]
                bar.update(1)
    log.info("generated %s under %s", ", ".join(f"{len(v)} {k}" for k, v in files.items()), config.out)
    return DemoSet(files, labels)
