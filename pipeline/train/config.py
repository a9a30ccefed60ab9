"""The train stage's settings (`TrainStageConfig`): the defaults of `cnep train`, and of `train()` from Python.

Importable without torch: the `cnep train` command walks these fields and those of the configs they hold
(`models.CNEPConfig`, `models.TrainConfig`) to offer its options with their defaults and help.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cnep.models.config import SCHEDULE_SHOWN, CNEPConfig, ConditioningPolicy, TrainConfig, setting
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.pipeline.train.constants import CONDITIONING, DEVICES, PRESET_NAMES, SCENE
from cnep.runtime.errors import PolicyError


def nll_beta_setting() -> object:
    """The training loss's beta-NLL power as the setting of a command that trains (`cnep demo`, `cnep sim`):
    `cnep train`'s default."""
    return setting(TrainConfig().nll_beta, "the training loss's beta-NLL power, as `cnep train --nll-beta` takes it")


def feature_components_setting() -> object:
    """The CNEP's feature components as the setting of a command that trains (`cnep sim`): `cnep train`'s default,
    the training schedule's."""
    return setting(
        CNEPConfig().feature_components,
        "principal components of the image features the CNEP and the CNMP read, as `cnep train "
        "--feature-components` takes them",
        shown=SCHEDULE_SHOWN,
    )


@dataclass(frozen=True)
class TrainStageConfig:
    """inputs: trajectory files or folders (read only); out: checkpoint folder (must not exist unless `force`).

    layout: preset name (wine-glass, scene, motion, all), which gives the model its columns; model: the network
    and its loss (models.CNEPConfig; its `columns` are the layout's); matched_cnmp: train instead the one-expert
    CNMP with that network's parameter count (models.matched_cnmp); training: steps, batch size (per process), lr,
    schedule, val_every, patience (validations), seed, threads (models.TrainConfig); conditioning: how a policy of
    the model conditions online and picks its active expert (runtime.ConditioningPolicy: window, anchors, first
    expert, switch margin and window), stored in config.json and in every policy made of it; val_fraction: share of the
    demonstrations held out for validation (whole demonstrations, at least one); candidates: with 2 or more, the
    checkpoint also holds that many candidate checkpoints for a choice after training (models.candidates);
    save_every: steps between resumable saves; device: cpu or cuda; resume: continue the unfinished run writing to
    `out`; force: replace an existing `out` when the run completes.
    """

    inputs: tuple[Path, ...]
    out: Path
    # scene: the gate must decide the behaviour (with wine-glass, the query's frame gives it away).
    layout: str = setting(
        SCENE,
        "columns observed/queried/predicted: wine-glass = observe features+pose+gripper, query features, predict "
        "pose+gripper (1288-d files); scene = the same, but queries carry the time only; motion = pose+gripper "
        "only (8-d files or the motion columns of 1288-d files); all = observe and predict every column",
        choices=PRESET_NAMES,
    )
    model: CNEPConfig = field(default_factory=CNEPConfig)
    matched_cnmp: bool = setting(
        False,
        "train the one-expert CNMP with the parameter count of the CNEP these options describe (its expert "
        "widened; the comparison the paper makes)",
    )
    training: TrainConfig = field(default_factory=TrainConfig)
    conditioning: ConditioningPolicy = field(default_factory=ConditioningPolicy)
    val_fraction: float = setting(0.2, "share of the demonstrations held out for validation")
    candidates: int = setting(
        1,
        "checkpoints kept for a choice after training: with N >= 2, OUT/candidates/ also holds N complete checkpoints, "
        "the weights with the lowest validation error in each of N equal parts of training (`cnep sim` chooses among "
        "them in closed loop); 1: the one checkpoint",
    )
    save_every: int = setting(500, "steps between resumable saves")
    device: str = setting("cpu", "where the network trains", choices=DEVICES)
    resume: bool = setting(False, "continue the interrupted run writing to --out")
    force: bool = setting(
        False,
        "replace an existing --out checkpoint (one `cnep train` recorded writing, holding nothing else, checked "
        "again) when training completes",
    )
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        if not 0 < self.val_fraction < 1:
            raise PipelineError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        if self.candidates < 1:
            raise PipelineError(f"candidates must be >= 1 checkpoint, got {self.candidates}")
        if self.save_every < 1:
            raise PipelineError(f"save_every must be >= 1 step, got {self.save_every}")


def checkpoint_conditioning(config: dict, path: Path) -> ConditioningPolicy:
    """The conditioning a checkpoint's config.json (`config`, read from `path`) stores: a policy of its model runs with
    it (a checkpoint written before it was stored: the defaults); PipelineError naming the file if it is malformed."""
    try:
        return ConditioningPolicy.from_dict(config.get(CONDITIONING))
    except PolicyError as exc:
        raise PipelineError(f"{path}: {exc}; retrain with `cnep train`") from None
