"""`cnep sim grid`'s settings (`GridConfig`): the closed-loop benchmark's cells, task x demonstration set x training
seed x demonstrations per behaviour x model, and where they run. Importable without torch, MuJoCo or Gymnasium: the
CLI builds it (and so checks its options) before the stage loads.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

from cnep.models.config import CNEPConfig, setting
from cnep.pipeline.demo.config import AUTO_WEIGHTS
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.addresses import check_executor
from cnep.pipeline.evaluate.constants import LOCAL
from cnep.pipeline.inputs import coerce_paths
from cnep.pipeline.sim.config import (
    BOTH,
    ENV_VERSION_HELP,
    ENV_VERSIONS,
    MAX_STEPS_HELP,
    ONLINE,
    PROTOCOL_HELP,
    PROTOCOLS,
    SIM_TASKS,
    check_env_version,
    check_episode_seeds,
    check_seeds,
    protocols_of,
)
from cnep.pipeline.sim.validation import VALIDATION_RANGE
from cnep.pipeline.train.config import feature_components_setting

# The settings every cell of one grid folder shares (GRID_FILE): a rerun into the folder with another value of one
# would mix cells of two benchmarks in its table.
SHARED = (
    "env_version", "per_behaviour", "train_steps", "feature_components", "episodes", "episode_seed", "max_steps",
    "protocol", "weights",
)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class GridConfig:
    """`cnep sim grid`: out, the grid's folder (new, or one this command wrote with the same SHARED settings: a rerun
    resumes it); tasks, the tasks with a `cnep sim TASK` command (both by default), every cell's models trained as it
    trains them; executor, `local` (`workers` processes here), `dask` or `ray` (pipeline.evaluate.executors) at
    `address` (None: a cluster of `workers` processes started on this machine)."""

    out: Path
    tasks: tuple[str, ...] = SIM_TASKS
    sets: tuple[int, ...] = setting(
        (0, 1, 2), "seeds of the demonstration sets (each set generated, ingested and extracted once, for every cell)"
    )
    train_seeds: tuple[int, ...] = setting((0, 1, 2, 3, 4), "training seeds: the CNEP and the CNMP trained per seed")
    per_behaviour: tuple[int, ...] = setting(
        (5, 10, 20, 40),
        "demonstrations per behaviour (side passed, place chosen) the models train on: the first ones of each "
        "behaviour in the set, which holds the largest number of each",
    )
    train_steps: int | None = setting(None, "training steps of each model")
    feature_components: int | None = feature_components_setting()
    env_version: int = setting(ENV_VERSIONS[-1], ENV_VERSION_HELP, choices=ENV_VERSIONS)
    episodes: int = setting(100, "closed-loop episodes per cell, protocol and condition")
    episode_seed: int = setting(
        0,
        f"seed of the first reported episode (episode i is reset with seed + i); the reported seeds may not overlap "
        f"the validation seeds, {VALIDATION_RANGE[0]}-{VALIDATION_RANGE[-1]}, which choose the kept checkpoints",
    )
    max_steps: int | None = setting(None, MAX_STEPS_HELP)
    protocol: str = setting(ONLINE, PROTOCOL_HELP, choices=(BOTH, *PROTOCOLS))
    baselines: bool = setting(
        False, "also run ProMP, GMM-GMR and nearest-demonstration retrieval, fitted beside each CNEP, as cells"
    )
    weights: str = setting(AUTO_WEIGHTS, "the feature network's weights, as `cnep demo --weights` takes them")
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")
    workers: int = setting(
        2,
        "processes running the cells side by side, on this machine or the cluster started here (0: one after "
        "another in the command's own process)",
    )
    executor: str = LOCAL
    address: str | None = None
    quiet: bool = field(default=False)

    def __post_init__(self) -> None:
        coerce_paths(self)
        unknown = [t for t in self.tasks if t not in SIM_TASKS]
        if unknown or not self.tasks:
            raise PipelineError(f"--tasks must name tasks among {', '.join(SIM_TASKS)}, got {' '.join(self.tasks)}")
        lists = {"--sets": self.sets, "--train-seeds": self.train_seeds, "--per-behaviour": self.per_behaviour}
        for option, values in lists.items():
            if not values or len(set(values)) < len(values):
                raise PipelineError(f"{option} takes distinct values, at least one, got {values}")
        for seed in self.sets:
            check_seeds(seed, self.train_seeds, "--sets")
        if min(self.per_behaviour) < 1 or (self.train_steps is not None and self.train_steps < 1):
            raise PipelineError(
                f"--per-behaviour and --train-steps must be >= 1, got {self.per_behaviour} and {self.train_steps}"
            )
        if self.episodes < 1 or (self.max_steps is not None and self.max_steps < 1) or self.workers < 0:
            raise PipelineError(
                f"episodes and max_steps must be >= 1 and workers >= 0, got {self.episodes}, {self.max_steps} and "
                f"{self.workers}"
            )
        CNEPConfig(feature_components=self.feature_components)  # ConfigError for a value `cnep train` refuses
        protocols_of(self.protocol)
        check_env_version(self.env_version)
        check_episode_seeds(self.episode_seed, self.episodes)  # refuses the validation seeds too
        check_executor(self.executor, self.address)

    @property
    def reported_seeds(self) -> range:
        """The episode seeds every cell is evaluated on, and the table reports."""
        return range(self.episode_seed, self.episode_seed + self.episodes)

    def shared(self) -> dict:
        """The settings every cell of the grid's folder shares (SHARED), as JSON writes them."""
        return {name: value for name, value in asdict(self).items() if name in SHARED}


def subset(behaviours: list[str], names: tuple[str, ...], d: int) -> list[int]:
    """The indices of the first `d` demonstrations of each behaviour in `names` (fewer where the set has fewer of
    one), in the set's order."""
    chosen = [i for name in names for i in [k for k, b in enumerate(behaviours) if b == name][:d]]
    return sorted(chosen)
