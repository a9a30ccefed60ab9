"""The closed loop's settings: `SimConfig` (`cnep sim obstacle`: from nothing to the table), `PickPlaceConfig` (`cnep
sim pick-place`) and `EvalConfig` (`cnep sim eval`: one given policy, on the task and the environments' version it
was trained on: `with_task`).
Importable without torch, MuJoCo, Gymnasium or rerun: the CLI builds them (and so checks its options) before the
stage loads; the tasks are the folders of cnep/sim/tasks, found without importing the simulator.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

from cnep.models.assignments import ASSIGNMENTS
from cnep.models.config import (
    SCHEDULE_SHOWN,
    SEED_MAX,
    CNEPConfig,
    ConditioningOverrides,
    TrainConfig,
    check_seed,
    setting,
)
from cnep.models.schedule import FEW_DEMONSTRATIONS
from cnep.perception.constants import DEFAULT_VIEWS, FEATURE_DIM, MAX_VIEWS
from cnep.pipeline.demo.config import AUTO_WEIGHTS
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths, read_json_object
from cnep.pipeline.run.config import CHECKPOINT, CONFIG_FILE, policy_kind
from cnep.pipeline.sim.validation import SelectionSettings, check_reported
from cnep.pipeline.train.config import feature_components_setting, nll_beta_setting
from cnep.pipeline.train.constants import TASKS as TASKS_KEY
from cnep.runtime.conditioning import ConditioningPolicy
from cnep.runtime.constants import MANIFEST_FILE


def task_names() -> tuple[str, ...]:
    """The simulator's tasks, one per folder of cnep/sim/tasks (`pick_place`: "pick-place", as sim.tasks names them),
    found without importing cnep.sim, which loads Gymnasium."""
    tasks = Path(importlib.util.find_spec("cnep.sim").submodule_search_locations[0]) / "tasks"
    return tuple(sorted(p.name.replace("_", "-") for p in tasks.iterdir() if (p / "__init__.py").is_file()))


TASKS = task_names()
OBSTACLE, PICK_PLACE = "obstacle", "pick-place"  # the tasks with a `cnep sim` command of their own
SIM_TASKS = (OBSTACLE, PICK_PLACE)  # their settings (SimConfig, PickPlaceConfig) train the grid's models
PLANNED, ONLINE = "planned", "online"  # cnep.sim.episode's protocols, named here without importing MuJoCo
PROTOCOLS = (PLANNED, ONLINE)
BOTH = "both"
PROTOCOL_HELP = (
    "planned = the motion planned from the first observation alone and executed by the controller; online = "
    "conditioning on every new frame and pose; both = each in turn"
)
MODELS = ("CNEP", "CNMP")
VARIANTS = ("cue",)  # LoopSettings' fields that choose a variant of a task (sim.task.Task.variants)
ENV_VERSIONS = (0, 1)  # the versions of the simulator's environments (each task folder's versions.py)
ENV_VERSION_HELP = (
    "the environments' version: 1 a robot's (an arm's speed and acceleration limits, sensing noise, wider scenes, the "
    "scene changing during the motion); 0 the first (the gripper jumping to each waypoint, exact sensing), as its "
    "results were measured"
)


def views_setting() -> object:
    """Views of each demonstration's frames the features are also extracted under, as a setting of a command that
    extracts (`cnep sim`): `cnep extract --views`'s default, the rule of the demonstrations' number."""
    return setting(
        None,
        "views of each demonstration's frames whose features the models also train on, as `cnep extract --views` "
        "takes them",
        shown=f"{DEFAULT_VIEWS} where fewer than {FEW_DEMONSTRATIONS} demonstrations are extracted, else 0",
    )


TRAIN_STEPS_HELP = "training steps of each model, as `cnep train --steps` takes them"
BASELINES_HELP = (
    "also run ProMP, GMM-GMR and nearest-demonstration retrieval per training seed, driven as the CNEP is, and a CNEP "
    "trained on their inputs (CNEP-PCA) in the loop"
)
PCA_HELP = (
    "principal components of the features the baselines and CNEP-PCA see beside the state (PCA fitted on the "
    "training frames)"
)
MAX_STEPS_HELP = (
    "control steps an episode gets before it is truncated (the planned protocol's plan spans the task's episode "
    "whatever the limit, its last waypoint held after them)"
)
FORCE_HELP = (
    "discard the stopped run that .OUT.partial beside --out holds (only the files it wrote) and start over; without "
    "it, a stopped run of the same settings resumes and one of other settings is refused"
)
# What a None default means, as `--help` shows it.
SHOWN = {
    "max_steps": "the task's episode, sim.task.Task.max_steps",
    "task": "the one the policy was trained on, as its export or checkpoint records",
}


def protocols_of(protocol: str) -> tuple[str, ...]:
    """The protocols a `protocol` setting (both, planned or online) runs, in order; PipelineError for another."""
    if protocol not in (BOTH, *PROTOCOLS):
        raise PipelineError(f"protocol must be one of {BOTH}, {', '.join(PROTOCOLS)}, got {protocol!r}")
    return PROTOCOLS if protocol == BOTH else (protocol,)


def check_episode_seeds(first: int, episodes: int) -> None:
    """PipelineError unless the episode seeds `first` .. `first + episodes - 1` are seeds (models.config.SEED_MAX)
    outside the validation seeds (pipeline.sim.validation)."""
    check_seed("--episode-seed", first, PipelineError)
    if first + episodes - 1 > SEED_MAX:
        raise PipelineError(
            f"--episode-seed {first} and --episodes {episodes} give episode seeds up to {first + episodes - 1}, more "
            f"than the largest seed, {SEED_MAX}"
        )
    check_reported(first, episodes)


def check_env_version(version: int | None) -> None:
    """PipelineError unless `version` is one of ENV_VERSIONS (or None: the policy's own, `cnep sim eval`)."""
    if version is not None and version not in ENV_VERSIONS:
        raise PipelineError(
            f"env_version must be one of {', '.join(map(str, ENV_VERSIONS))} (the environments' versions), got "
            f"{version!r}"
        )


def demonstrations_task(task: str, version: int) -> str:
    """The task `cnep sim` names its demonstrations with on the environments' `version` (and so the one its
    checkpoints and exports record): the task's name on version 0, `NAME-vN` on version N >= 1."""
    return task if version == 0 else f"{task}-v{version}"


def task_and_version(label: str) -> tuple[str, int | None]:
    """The simulator's task and environments' version a demonstrations' task `label` names (demonstrations_task's
    inverse: a task's bare name is its version 0); ("", None) for a label that names no task of the simulator."""
    name, _, version = label.rpartition("-v")
    if name in TASKS and version.isdigit() and int(version) in ENV_VERSIONS[1:]:
        return name, int(version)
    return (label, 0) if label in TASKS else ("", None)


def check_seeds(seed: int, train_seeds: tuple[int, ...], seed_option: str = "--seed") -> None:
    """PipelineError unless the demonstrations' `seed` (given as `seed_option`) and every one of `train_seeds` is a
    seed, the training seeds distinct (each names its models' checkpoints)."""
    check_seed(seed_option, seed, PipelineError)
    if len(set(train_seeds)) < len(train_seeds):
        raise PipelineError(f"--train-seeds takes distinct values, got {','.join(map(str, train_seeds))}")
    for train_seed in train_seeds:
        check_seed("--train-seeds", train_seed, PipelineError)


def assignment_setting() -> object:
    """The CNEP's assignment as a `cnep sim` task's setting: `cnep train`'s default."""
    return setting(
        CNEPConfig().assignment,
        "the CNEP's assignment, as `cnep train --assignment` takes it",
        choices=tuple(ASSIGNMENTS),
    )


def check_training(config: SimConfig | PickPlaceConfig) -> None:
    """PipelineError unless `config` trains on >= 2 demonstrations, for >= 1 step (where given), with >= 2 experts and
    a training seed; ConfigError, before any work, where its training settings are ones `cnep train` refuses
    (TrainConfig's and CNEPConfig's own checks, which the models' training would meet only after the demonstrations
    are made), or where its views are more than `cnep extract` takes."""
    if (
        config.demonstrations < 2
        or (config.train_steps is not None and config.train_steps < 1)
        or config.experts < 2
        or not config.train_seeds
    ):
        raise PipelineError(
            f"need >= 2 demonstrations, >= 1 training step, >= 2 experts and a training seed, got "
            f"{config.demonstrations}, {config.train_steps}, {config.experts} and {config.train_seeds}"
        )
    TrainConfig(steps=config.train_steps, nll_beta=config.nll_beta)
    CNEPConfig(feature_components=config.feature_components)
    if config.views is not None and not 0 <= config.views <= MAX_VIEWS:
        raise PipelineError(f"--views must be a whole number from 0 to {MAX_VIEWS}, got {config.views}")


@dataclass(frozen=True)
class LoopSettings:
    """What every closed-loop evaluation takes: the task's variant, the episodes and the recordings of them, and
    the conditioning settings given to replace the policy's own."""

    cue: bool = setting(False, "the obstacle task's variant where a tile on one side of the box shows the side to pass")
    env_version: int | None = setting(ENV_VERSIONS[-1], ENV_VERSION_HELP, choices=ENV_VERSIONS)
    episodes: int = setting(20, "closed-loop episodes per policy and protocol")
    max_steps: int | None = setting(None, MAX_STEPS_HELP)
    episode_seed: int = setting(0, "seed of the first episode (episode i is reset with seed + i)")
    protocol: str = setting(BOTH, PROTOCOL_HELP, choices=(BOTH, *PROTOCOLS))
    record: int = setting(2, "episodes per policy and protocol written as Rerun recordings (the first ones)")
    # What replaces the policy's own conditioning (its manifest's, its checkpoint's) in these episodes.
    conditioning: ConditioningOverrides = field(default_factory=ConditioningOverrides)

    @property
    def protocols(self) -> tuple[str, ...]:
        """The protocols to run, in order."""
        return protocols_of(self.protocol)

    def check(self) -> None:
        """PipelineError for a setting out of range."""
        protocols_of(self.protocol)
        check_env_version(self.env_version)
        if self.episodes < 1 or (self.max_steps is not None and self.max_steps < 1) or self.record < 0:
            raise PipelineError(
                f"episodes and max_steps must be >= 1 and record >= 0, got {self.episodes}, {self.max_steps} and "
                f"{self.record}"
            )
        check_episode_seeds(self.episode_seed, self.episodes)


@dataclass(frozen=True, kw_only=True)
class SimConfig(LoopSettings):
    """`cnep sim obstacle`: out, a new or empty folder for everything; on the environments' version `env_version`,
    demonstrations generated with `seed`, the features' `weights` (`auto`: ImageNet's where they can be had, else
    seeded random ones: pipeline.demo.weights), one CNEP and one matched CNMP per training seed, each exported and run
    in closed loop."""

    TASK: ClassVar[str] = OBSTACLE
    out: Path
    demonstrations: int = setting(40, "demonstrations generated (half pass left, half right)")
    seed: int = setting(0, "seed of the demonstrations (and of the feature network's random weights)")
    train_seeds: tuple[int, ...] = setting((0,), "training seeds: one CNEP and one matched CNMP trained per seed")
    train_steps: int | None = setting(None, TRAIN_STEPS_HELP, shown=SCHEDULE_SHOWN)
    experts: int = setting(2, "the CNEP's experts (the CNMP: one, parameter-matched)")
    assignment: str = assignment_setting()
    nll_beta: float = nll_beta_setting()
    feature_components: int | None = feature_components_setting()
    views: int | None = views_setting()
    weights: str = setting(AUTO_WEIGHTS, "the feature network's weights, as `cnep demo --weights` takes them")
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")
    baselines: bool = setting(False, BASELINES_HELP)
    pca: int = setting(8, PCA_HELP)
    selection: SelectionSettings = field(default_factory=SelectionSettings)  # the kept checkpoint's choice
    force: bool = setting(False, FORCE_HELP)
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        self.check()
        check_seeds(self.seed, self.train_seeds)
        check_training(self)
        if not 1 <= self.pca <= FEATURE_DIM:
            raise PipelineError(f"--pca must be from 1 to {FEATURE_DIM} (the features' width), got {self.pca}")


@dataclass(frozen=True, kw_only=True)
class EvalConfig(LoopSettings):
    """`cnep sim eval`: policy, a folder written by `cnep export` or `cnep train`; out, a new or empty folder for
    the summary and the recordings (None: the table only); extractor: a checkpoint's feature weights."""

    policy: Path
    out: Path | None = None
    task: str | None = setting(None, "the task", choices=TASKS)
    env_version: int | None = setting(
        None, ENV_VERSION_HELP, choices=ENV_VERSIONS, shown="the one the policy was trained on, as its task records"
    )
    episodes: int = setting(50, "closed-loop episodes per protocol (and condition, where the task has conditions)")
    extractor: Path | None = None
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        self.check()
        if self.task is not None and self.task not in TASKS:
            raise PipelineError(f"task must be one of {', '.join(TASKS)}, got {self.task!r}")


def with_task(config: EvalConfig) -> EvalConfig:
    """`config` with its task and environments' version: those given, else those the policy was trained on
    (policy_task, task_and_version; a policy that names no task of the simulator runs on the latest version);
    PipelineError when the given task differs from the policy's, or when neither names a task of the simulator."""
    trained, version = task_and_version(policy_task(Path(config.policy)))
    if config.task is None and not trained:
        label = policy_task(Path(config.policy))
        named = f"names the task {label!r}, not one of the simulator's" if label else "names no task"
        raise PipelineError(f"{config.policy}: the policy {named}; choose its scene with --task {'|'.join(TASKS)}")
    if config.task is not None and trained and trained != config.task:
        raise PipelineError(
            f"{config.policy}: the policy was trained on the {trained} task, --task {config.task} runs it in another "
            f"scene; leave --task out (or give --task {trained})"
        )
    chosen = config.env_version if config.env_version is not None else version
    return replace(config, task=config.task or trained, env_version=ENV_VERSIONS[-1] if chosen is None else chosen)


def policy_task(policy: Path) -> str:
    """The task a policy folder was trained on: the one task its training demonstrations name (an export's
    `spec.tasks` in its manifest, a checkpoint's `tasks` in its config.json); "" where they name none or several."""
    checkpoint = policy_kind(policy) == CHECKPOINT
    path = policy / (CONFIG_FILE if checkpoint else MANIFEST_FILE)
    what = "the checkpoint's config" if checkpoint else "the policy's manifest"
    data = read_json_object(path, what, "export or train the policy again")
    holder = data if checkpoint else data.get("spec") or {}
    tasks = (holder.get(TASKS_KEY) if isinstance(holder, dict) else None) or []
    if not (isinstance(tasks, list) and all(isinstance(task, str) for task in tasks)):
        raise PipelineError(f"{path}: its tasks are not a list of task names; export or train the policy again")
    return tasks[0] if len(tasks) == 1 else ""


@dataclass(frozen=True, kw_only=True)
class PickPlaceConfig:
    """`cnep sim pick-place`: out, a new or empty folder for everything; on the environments' version `env_version`,
    demonstrations generated with `seed`, the features' `weights`, one CNEP and one matched CNMP per training seed (and
    the baselines), each run in closed loop by each protocol in every condition."""

    TASK: ClassVar[str] = PICK_PLACE
    out: Path
    demonstrations: int = setting(96, "demonstrations generated (each a scene drawn decided or free, its place drawn)")
    seed: int = setting(0, "seed of the demonstrations (and of the feature network's random weights)")
    train_seeds: tuple[int, ...] = setting((0,), "training seeds: one CNEP and one matched CNMP trained per seed")
    train_steps: int | None = setting(None, TRAIN_STEPS_HELP, shown=SCHEDULE_SHOWN)
    experts: int = setting(4, "the CNEP's experts (the CNMP: one, parameter-matched)")
    env_version: int = setting(ENV_VERSIONS[-1], ENV_VERSION_HELP, choices=ENV_VERSIONS)
    assignment: str = assignment_setting()
    nll_beta: float = nll_beta_setting()
    feature_components: int | None = feature_components_setting()
    views: int | None = views_setting()
    weights: str = setting(AUTO_WEIGHTS, "the feature network's weights, as `cnep demo --weights` takes them")
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")
    episodes: int = setting(20, "closed-loop episodes per policy, protocol and condition (decided, free, changed)")
    max_steps: int | None = setting(None, MAX_STEPS_HELP)
    episode_seed: int = setting(0, "seed of the first episode (episode i is reset with seed + i)")
    protocol: str = setting(BOTH, PROTOCOL_HELP, choices=(BOTH, *PROTOCOLS))
    record: int = setting(1, "episodes per policy, protocol and condition written as Rerun recordings (the first ones)")
    baselines: bool = setting(True, BASELINES_HELP)
    pca: int = setting(8, PCA_HELP)
    selection: SelectionSettings = field(default_factory=SelectionSettings)  # the kept checkpoint's choice
    # What replaces ConditioningPolicy's defaults in the models it trains (their config.json, their exports).
    conditioning: ConditioningOverrides = field(default_factory=ConditioningOverrides)
    force: bool = setting(False, FORCE_HELP)
    quiet: bool = False

    @property
    def protocols(self) -> tuple[str, ...]:
        """The protocols to run, in order."""
        return protocols_of(self.protocol)

    def __post_init__(self) -> None:
        coerce_paths(self)
        protocols_of(self.protocol)
        check_env_version(self.env_version)
        check_training(self)
        if self.episodes < 1 or (self.max_steps is not None and self.max_steps < 1) or self.record < 0 or self.pca < 1:
            raise PipelineError(
                f"episodes, max_steps and pca must be >= 1 and record >= 0, got {self.episodes}, {self.max_steps}, "
                f"{self.pca} and {self.record}"
            )
        if self.pca > FEATURE_DIM:
            raise PipelineError(f"--pca must be from 1 to {FEATURE_DIM} (the features' width), got {self.pca}")
        check_seeds(self.seed, self.train_seeds)
        check_episode_seeds(self.episode_seed, self.episodes)


def trained_conditioning(config: SimConfig | PickPlaceConfig) -> ConditioningPolicy:
    """The conditioning a `cnep sim` run trains into its models (config.json, and so the exported manifest and every
    Policy of them): ConditioningPolicy's defaults, `cnep train`'s, but for the run's conditioning options."""
    return config.conditioning.applied(ConditioningPolicy())
