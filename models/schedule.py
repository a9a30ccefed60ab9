"""The training schedule: steps, learning-rate warm-up, validation interval, the feature components and the online
contexts as one rule of the training data.

Every trainer (`models.fit`, `cnep train`, `cnep sim`, the demo, the Baxter example) leaves `TrainConfig.steps`,
`warmup_steps`, `val_every` and `CNEPConfig.feature_components` unset (None) unless they are given, and `scheduled`
and `with_components` fill them from the number of demonstrations the model trains on (those not held out for
validation, over every process):

- steps: BASE_STEPS, or more where the data is larger, so that each training demonstration is drawn into a batch
  DRAWS_PER_DEMONSTRATION times on average (rounded up to a multiple of ROUND_STEPS);
- warm-up: WARMUP_SHARE of the steps, at most MAX_WARMUP;
- validation: VALIDATIONS times over the steps, at most every MAX_VAL_EVERY steps;
- feature components: where a model trains on fewer than FEW_DEMONSTRATIONS demonstrations and observes more columns
  that it does not predict (a camera's 1280 features), the encoder reads those columns as their principal components,
  as many as the demonstrations (`components_for`; each view of a demonstration's frames counts as one more,
  `schedule_of`'s `scenes`). A few dozen scenes differ along at most that many directions of the features; read
  whole, the rest tells each training scene apart by its own clutter, and the model recalls its training scenes
  instead of reading a new one. With more demonstrations every column is read as it is, as the
  demo's and the obstacle's larger sets read best (docs/concepts.md).
- online contexts: a model that observes columns it does not predict (a camera's features) is a policy, conditioned
  step by step on what it has seen so far (runtime.ConditioningPolicy); ONLINE_SHARE of its training contexts are
  that (`TrainConfig.online_contexts`, models.sampler). A motion-only model keeps the paper's random contexts, the
  via-points it is conditioned on (`online_contexts_for`).

The warm-up and the validation interval follow the steps whether those were given or scheduled. Patience is counted
in validations (`TrainConfig.patience`, not scheduled): its default is more than the validations of BASE_STEPS, so it
only cuts a longer run. No torch: the CLI and config.json's readers import it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from cnep.models.config import CNEPConfig, TrainConfig

log = logging.getLogger(__name__)

# The steps every open-loop result was measured at (docs/results.md: the demo, commitment, the paper's sets, Baxter).
BASE_STEPS = 4_000
# The largest data those were measured on (the 6-mode sets' 307 training demonstrations) drew each demonstration about
# 417 times in BASE_STEPS steps of 32 samples: larger data gets the steps that keep that many draws.
DRAWS_PER_DEMONSTRATION = 400
ROUND_STEPS = 100
WARMUP_SHARE, MAX_WARMUP = 0.5, 2_000
VALIDATIONS, MAX_VAL_EVERY = 8, 500
FEW_DEMONSTRATIONS = 64  # under this many training demonstrations, image features are read as one component each
ONLINE_SHARE = 1.0  # the training contexts shaped as the policy's conditioning, where a model reads a camera
# The share of those contexts at step 0 (models.sampler): the policy's first read, from which it takes its first expert
# and commits, drawn that much more often than any later step.
FIRST_READ_SHARE = 0.25
SCHEDULED = ("steps", "warmup_steps", "val_every", "online_contexts")  # the TrainConfig fields filled when None


@dataclass(frozen=True)
class Schedule:
    """What the rule gave a training run: its input (`demonstrations`: training demonstrations, `batch_size`: samples
    per step over every process, `scenes`: the training demonstrations and their views, perception.views), the values
    it trains with (`feature_components`: None or 0, every column as it is; `online_contexts`: the share of contexts
    shaped as the policy's conditioning) and the names of those given rather than scheduled. config.json holds it
    under `training.schedule`."""

    demonstrations: int
    batch_size: int
    scenes: int
    steps: int
    warmup_steps: int
    val_every: int
    feature_components: int | None
    online_contexts: float
    given: tuple[str, ...]

    def to_dict(self) -> dict:
        return {
            "inputs": {"demonstrations": self.demonstrations, "batch_size": self.batch_size, "scenes": self.scenes},
            "steps": self.steps,
            "warmup_steps": self.warmup_steps,
            "val_every": self.val_every,
            "feature_components": self.feature_components,
            "online_contexts": self.online_contexts,
            "given": list(self.given),
        }


def scheduled_steps(demonstrations: int, batch_size: int) -> int:
    """Training steps for `demonstrations` training demonstrations drawn `batch_size` per step (module docstring)."""
    needed = math.ceil(DRAWS_PER_DEMONSTRATION * demonstrations / batch_size / ROUND_STEPS) * ROUND_STEPS
    return max(BASE_STEPS, needed)


def warmup_for(steps: int) -> int:
    """Warm-up steps of a run of `steps` steps."""
    return min(int(steps * WARMUP_SHARE), MAX_WARMUP)


def val_every_for(steps: int) -> int:
    """Steps between validations in a run of `steps` steps."""
    return max(1, min(steps // VALIDATIONS, MAX_VAL_EVERY))


def components_for(observed_only: int, demonstrations: int) -> int | None:
    """The principal components the encoder reads `observed_only` columns (observed, never predicted) as, trained on
    `demonstrations` demonstrations: as many as the demonstrations where those are fewer than FEW_DEMONSTRATIONS and
    than the columns, else None (every column as it is)."""
    return demonstrations if demonstrations < min(FEW_DEMONSTRATIONS, observed_only) else None


def online_contexts_for(observed_only: int) -> float:
    """The share of training contexts shaped as the policy's conditioning for a model that observes `observed_only`
    columns it does not predict: ONLINE_SHARE where it observes any (a camera), else 0 (the paper's contexts)."""
    return ONLINE_SHARE if observed_only else 0.0


def with_components(model: CNEPConfig, demonstrations: int) -> CNEPConfig:
    """`model` with its `feature_components` the rule's (`components_for`) for `demonstrations` training
    demonstrations where unset; unchanged where given."""
    if model.feature_components is not None:
        return model
    return replace(model, feature_components=components_for(len(model.columns.observed_only), demonstrations))


def schedule_of(
    training: TrainConfig,
    demonstrations: int,
    world_size: int = 1,
    model: CNEPConfig | None = None,
    scenes: int | None = None,
) -> Schedule:
    """The schedule of `training` and `model` (None: one that observes nothing it does not predict) for
    `demonstrations` training demonstrations (every process's), `world_size` processes each drawing
    `training.batch_size` samples a step, the features seen in `scenes` scenes (the demonstrations and their views;
    None: the demonstrations alone): its given values kept, the others the rule's."""
    scenes = demonstrations if scenes is None else scenes
    model = CNEPConfig() if model is None else model
    batch = training.batch_size * world_size
    steps = training.steps if training.steps is not None else scheduled_steps(demonstrations, batch)
    warmup = training.warmup_steps if training.warmup_steps is not None else warmup_for(steps)
    val_every = training.val_every if training.val_every is not None else val_every_for(steps)
    components = with_components(model, scenes).feature_components
    online = training.online_contexts
    if online is None:
        online = online_contexts_for(len(model.columns.observed_only))
    given = tuple(name for name in SCHEDULED if getattr(training, name) is not None)
    if model.feature_components is not None:
        given += ("feature_components",)
    if warmup >= steps:
        log.warning("a warm-up of %d steps in %d steps: the learning rate never reaches its peak", warmup, steps)
    return Schedule(demonstrations, batch, scenes, steps, warmup, val_every, components, online, given)


def scheduled(
    training: TrainConfig, demonstrations: int, world_size: int = 1, model: CNEPConfig | None = None
) -> TrainConfig:
    """`training` with its unset schedule settings filled in (schedule_of, for `model`); unchanged where all are
    set."""
    made = schedule_of(training, demonstrations, world_size, model)
    return replace(
        training,
        steps=made.steps,
        warmup_steps=made.warmup_steps,
        val_every=made.val_every,
        online_contexts=made.online_contexts,
    )
