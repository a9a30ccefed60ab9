"""The closed loop's settings: `SimConfig` (`cnep sim obstacle`: from nothing to the table) and `EvalConfig`
(`cnep sim eval`: one given policy). Importable without torch, MuJoCo or rerun: the CLI builds them (and so checks
its options) before the stage loads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cnep.models.assignments import ASSIGNMENTS
from cnep.models.config import SEED_MAX, check_seed, setting
from cnep.perception.constants import FEATURE_DIM
from cnep.pipeline.demo.config import AUTO_WEIGHTS
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.runtime.conditioning import FIRST_EXPERTS, ConditioningPolicy
from cnep.sim import pick_scene, scene

OBSTACLE = "obstacle"
TASKS = (OBSTACLE,)
PLANNED, ONLINE = "planned", "online"  # cnep.sim.episode's protocols, named here without importing MuJoCo
PROTOCOLS = (PLANNED, ONLINE)
BOTH = "both"
PROTOCOL_HELP = (
    "planned = the motion planned from the first observation alone and executed by the controller; online = "
    "conditioning on every new frame and pose; both = each in turn"
)
MODELS = ("CNEP", "CNMP")


def _max_steps_help(task_steps: int) -> str:
    """The help of a task's `max_steps`, whose default is the task's own `task_steps`."""
    return (
        f"control steps an episode gets before it is truncated (the planned protocol's plan spans the task's "
        f"{task_steps} steps whatever the limit, its last waypoint held after them)"
    )


def protocols_of(protocol: str) -> tuple[str, ...]:
    """The protocols a `protocol` setting (both, planned or online) runs, in order; PipelineError for another."""
    if protocol not in (BOTH, *PROTOCOLS):
        raise PipelineError(f"protocol must be one of {BOTH}, {', '.join(PROTOCOLS)}, got {protocol!r}")
    return PROTOCOLS if protocol == BOTH else (protocol,)


def check_episode_seeds(first: int, episodes: int) -> None:
    """PipelineError unless the episode seeds `first` .. `first + episodes - 1` are seeds (models.config.SEED_MAX)."""
    check_seed("--episode-seed", first, PipelineError)
    if first + episodes - 1 > SEED_MAX:
        raise PipelineError(
            f"--episode-seed {first} and --episodes {episodes} give episode seeds up to {first + episodes - 1}, more "
            f"than the largest seed, {SEED_MAX}"
        )


def check_seeds(seed: int, train_seeds: tuple[int, ...]) -> None:
    """PipelineError unless the demonstrations' `seed` and every one of `train_seeds` is a seed."""
    check_seed("--seed", seed, PipelineError)
    for train_seed in train_seeds:
        check_seed("--train-seeds", train_seed, PipelineError)


@dataclass(frozen=True)
class LoopSettings:
    """What every closed-loop evaluation takes: the task and its variant, the episodes and the recordings of them."""

    task: str = setting(OBSTACLE, "the task", choices=TASKS)
    cue: bool = setting(False, "the variant where a tile on one side of the box shows the side to pass")
    episodes: int = setting(20, "closed-loop episodes per policy and protocol")
    max_steps: int = setting(scene.MAX_STEPS, _max_steps_help(scene.MAX_STEPS))
    episode_seed: int = setting(0, "seed of the first episode (episode i is reset with seed + i)")
    protocol: str = setting(BOTH, PROTOCOL_HELP, choices=(BOTH, *PROTOCOLS))
    record: int = setting(2, "episodes per policy and protocol written as Rerun recordings (the first ones)")
    first_expert: str = setting(
        ConditioningPolicy.first_expert,
        "the first active expert of an episode: argmax (the gate's winner, every episode alike) or sample (drawn "
        "from the gate with the episode's seed: episodes split between behaviours as the demonstrations do)",
        choices=FIRST_EXPERTS,
    )

    @property
    def protocols(self) -> tuple[str, ...]:
        """The protocols to run, in order."""
        return protocols_of(self.protocol)

    def check(self) -> None:
        """PipelineError for a setting out of range."""
        if self.task not in TASKS:
            raise PipelineError(f"task must be one of {', '.join(TASKS)}, got {self.task!r}")
        protocols_of(self.protocol)
        if self.episodes < 1 or self.max_steps < 1 or self.record < 0:
            raise PipelineError(
                f"episodes and max_steps must be >= 1 and record >= 0, got {self.episodes}, {self.max_steps} and "
                f"{self.record}"
            )
        check_episode_seeds(self.episode_seed, self.episodes)


@dataclass(frozen=True, kw_only=True)
class SimConfig(LoopSettings):
    """`cnep sim obstacle`: out, a new or empty folder for everything; demonstrations generated with `seed`, the
    features' `weights` (`auto`: ImageNet's where they can be had, else seeded random ones: pipeline.demo.weights),
    one CNEP and one matched CNMP per training seed, each exported and run in closed loop."""

    out: Path
    demonstrations: int = setting(40, "demonstrations generated (half pass left, half right)")
    seed: int = setting(0, "seed of the demonstrations (and of the feature network's random weights)")
    train_seeds: tuple[int, ...] = setting((0,), "training seeds: one CNEP and one matched CNMP trained per seed")
    train_steps: int = setting(3000, "training steps of each model")
    experts: int = setting(2, "the CNEP's experts (the CNMP: one, parameter-matched)")
    # The demonstrations pass left and right alike, and an expert that reads the side from a start it has memorised
    # takes both sides where a share left free to drift allows it: equal shares until the experts commit keep them
    # one side each (docs/results-closed-loop.md).
    assignment: str = setting(
        "annealed", "the CNEP's assignment, as `cnep train --assignment` takes it", choices=tuple(ASSIGNMENTS)
    )
    nll_beta: float = setting(0.0, "the training loss's beta-NLL power, as `cnep train --nll-beta` takes it")
    weights: str = setting(AUTO_WEIGHTS, "the feature network's weights, as `cnep demo --weights` takes them")
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        self.check()
        check_seeds(self.seed, self.train_seeds)
        if self.demonstrations < 2 or self.train_steps < 1 or self.experts < 2 or not self.train_seeds:
            raise PipelineError(
                f"need >= 2 demonstrations, >= 1 training step, >= 2 experts and a training seed, got "
                f"{self.demonstrations}, {self.train_steps}, {self.experts} and {self.train_seeds}"
            )


@dataclass(frozen=True, kw_only=True)
class EvalConfig(LoopSettings):
    """`cnep sim eval`: policy, a folder written by `cnep export` or `cnep train`; out, a new or empty folder for
    the summary and the recordings (None: the table only); extractor: a checkpoint's feature weights."""

    policy: Path
    out: Path | None = None
    episodes: int = setting(50, "closed-loop episodes per protocol")
    extractor: Path | None = None
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        self.check()


@dataclass(frozen=True, kw_only=True)
class PickPlaceConfig:
    """`cnep sim pick-place`: out, a new or empty folder for everything; demonstrations generated with `seed`, the
    features' `weights`, one CNEP and one matched CNMP per training seed (and the baselines), each run in closed loop
    by each protocol in every condition."""

    out: Path
    demonstrations: int = setting(96, "demonstrations generated (each a scene drawn decided or free, its place drawn)")
    seed: int = setting(0, "seed of the demonstrations (and of the feature network's random weights)")
    train_seeds: tuple[int, ...] = setting((0,), "training seeds: one CNEP and one matched CNMP trained per seed")
    train_steps: int = setting(3000, "training steps of each model")
    experts: int = setting(4, "the CNEP's experts (the CNMP: one, parameter-matched)")
    assignment: str = setting(
        "annealed", "the CNEP's assignment, as `cnep train --assignment` takes it", choices=tuple(ASSIGNMENTS)
    )
    # Where a motion heads (which mat) is read from the context, beside values the model predicts closely (the
    # heights, the gripper): with plain NLL those outweigh it and the place's mean stops being learned.
    nll_beta: float = setting(0.5, "the training loss's beta-NLL power, as `cnep train --nll-beta` takes it")
    weights: str = setting(AUTO_WEIGHTS, "the feature network's weights, as `cnep demo --weights` takes them")
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")
    # A cup can move during the motion: the start's frame, kept in the context for the whole episode, would go on
    # showing the old table, and a long window dilutes the change's evidence; a short window of recent steps alone
    # switches expert within a few steps of the change.
    window: int = setting(
        4, "latest observations in the CNEP's and the CNMP's conditioning set (runtime.ConditioningPolicy.window)"
    )
    anchors: int = setting(0, "first observations kept in that set for the whole episode (ConditioningPolicy.anchors)")
    episodes: int = setting(20, "closed-loop episodes per policy, protocol and condition (decided, free, changed)")
    max_steps: int = setting(pick_scene.MAX_STEPS, _max_steps_help(pick_scene.MAX_STEPS))
    episode_seed: int = setting(0, "seed of the first episode (episode i is reset with seed + i)")
    protocol: str = setting(BOTH, PROTOCOL_HELP, choices=(BOTH, *PROTOCOLS))
    record: int = setting(1, "episodes per policy, protocol and condition written as Rerun recordings (the first ones)")
    baselines: bool = setting(
        True, "also run ProMP and GMM-GMR (on PCA-reduced features) and nearest-demonstration retrieval in the loop"
    )
    pca: int = setting(8, "principal components of the features the baselines see (PCA fitted on the training frames)")
    quiet: bool = False

    @property
    def protocols(self) -> tuple[str, ...]:
        """The protocols to run, in order."""
        return protocols_of(self.protocol)

    def __post_init__(self) -> None:
        coerce_paths(self)
        protocols_of(self.protocol)
        if self.demonstrations < 2 or self.train_steps < 1 or self.experts < 2 or not self.train_seeds:
            raise PipelineError(
                f"need >= 2 demonstrations, >= 1 training step, >= 2 experts and a training seed, got "
                f"{self.demonstrations}, {self.train_steps}, {self.experts} and {self.train_seeds}"
            )
        if self.window < 1 or self.anchors < 0:
            raise PipelineError(f"window must be >= 1 and anchors >= 0, got {self.window} and {self.anchors}")
        if self.episodes < 1 or self.max_steps < 1 or self.record < 0 or self.pca < 1:
            raise PipelineError(
                f"episodes, max_steps and pca must be >= 1 and record >= 0, got {self.episodes}, {self.max_steps}, "
                f"{self.pca} and {self.record}"
            )
        if self.pca > FEATURE_DIM:
            raise PipelineError(f"--pca must be from 1 to {FEATURE_DIM} (the features' width), got {self.pca}")
        check_seeds(self.seed, self.train_seeds)
        check_episode_seeds(self.episode_seed, self.episodes)
