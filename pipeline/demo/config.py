"""The demo's settings (`DemoConfig`) and sizes (`FULL`, `QUICK`): what `cnep demo` runs, without importing torch."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from cnep.models.config import CNEPConfig, TrainConfig, check_seed, setting
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.pipeline.train.config import nll_beta_setting

# `weights` by name (anything else is the path of a state dict): `auto` is ImageNet's where they can be had, else
# seeded random ones (pipeline.demo.weights); the other two are `cnep extract --weights`'s names (perception.weights).
AUTO_WEIGHTS, IMAGENET_WEIGHTS, RANDOM_WEIGHTS = "auto", "imagenet", "random"
CNEP_EXPERTS = 4  # the CNEP's default: one expert per behaviour of the scene


@dataclass(frozen=True)
class DemoSize:
    """How much the demo generates and trains: demonstrations per behaviour, steps per episode, training steps.

    free_choice_per_side / heldout_free_choice_per_side: training / held-out free-choice demonstrations
    per cup side; train_steps, val_every, warmup_steps: the training's, None where the training schedule's
    (models.schedule: a rule of the training demonstrations, as `cnep train` without those options);
    side_by_side: train the CNEP and the CNMP at once, in a process each (a process takes seconds to start, more than
    a few training steps take: a small size trains them one after the other in the demo's own process); views: the
    views of each demonstration's frames extracted, None where `cnep extract`'s rule for the training split's size
    gives them (pipeline.extract.stage.views_for).
    """

    per_behaviour: int
    heldout_per_behaviour: int
    free_choice_per_side: int
    heldout_free_choice_per_side: int
    steps: int
    train_steps: int | None = None
    val_every: int | None = None
    warmup_steps: int | None = None
    side_by_side: bool = True
    views: int | None = None


FULL = DemoSize(
    per_behaviour=30,
    heldout_per_behaviour=5,
    free_choice_per_side=20,
    heldout_free_choice_per_side=10,
    steps=40,
)
QUICK = DemoSize(
    per_behaviour=2,
    heldout_per_behaviour=1,
    free_choice_per_side=2,
    heldout_free_choice_per_side=1,
    steps=16,
    train_steps=60,
    val_every=20,
    warmup_steps=6,
    side_by_side=False,
    views=1,  # the views' path exercised in a quarter of the rule's extraction (two passes over the frames, not eight)
)


@dataclass(frozen=True)
class DemoConfig:
    """out: folder for everything (created; must be empty or absent unless `force`, which first deletes what an
    earlier demo recorded writing there, and refuses a folder holding anything else); quick: the small CI variant;
    seed: all draws; model: the CNEP's network and loss (models.CNEPConfig; the CNMP is the one-expert network of its
    parameter count, trained with the paper's term); nll_beta: both models' beta-NLL power; precision: the feature
    extraction's, `fp32` or `int8` (pipeline.extract.stage.ExtractConfig); weights: the feature network's
    (pipeline.demo.weights): `auto` (ImageNet weights where they can be had, else seeded random weights, with a
    warning), `imagenet`, `random` or the path of a MobileNet-v2 state dict; offline: never download ImageNet weights
    (as the environment variable CNEP_OFFLINE). The training follows the size (`FULL`, `QUICK`). A failed or
    interrupted demo leaves a new folder empty."""

    out: Path
    quick: bool = setting(
        False, "a small, fast variant (for CI): fewer demonstrations, shorter episodes, a few training steps"
    )
    seed: int = setting(0, "seed of every random draw")
    force: bool = setting(
        False,
        "use a non-empty --out folder: first delete what an earlier demo recorded writing there (refused if the "
        "folder holds anything else, another command's outputs included)",
    )
    quiet: bool = False
    model: CNEPConfig = field(default_factory=partial(CNEPConfig, n_experts=CNEP_EXPERTS))
    nll_beta: float = nll_beta_setting()
    precision: str = setting(
        "fp32", "feature extraction precision (int8 as `cnep extract --precision int8`)", choices=("fp32", "int8")
    )
    weights: str = setting(
        AUTO_WEIGHTS,
        "the feature network's weights: `auto`, ImageNet's where they can be had (the torch hub cache, "
        "$CNEP_MOBILENET_WEIGHTS, or a download into the cache) and else seeded random weights calibrated on the "
        "training frames, with a warning saying why; `imagenet`, the same but an error instead of random weights; "
        "`random`; or the path of a MobileNet-v2 state dict",
    )
    offline: bool = setting(False, "never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)")

    def __post_init__(self) -> None:
        coerce_paths(self)
        check_seed("--seed", self.seed, PipelineError)
        TrainConfig(nll_beta=self.nll_beta)  # ConfigError, before any work, for a value `cnep train` refuses

    @property
    def size(self) -> DemoSize:
        return QUICK if self.quick else FULL
