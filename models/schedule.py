"""The training schedule: steps, learning-rate warm-up and validation interval as one rule of the training data.

Every trainer (`models.fit`, `cnep train`, `cnep sim`, the demo, the Baxter example) leaves `TrainConfig.steps`,
`warmup_steps` and `val_every` unset (None) unless they are given, and `scheduled` fills them from the number of
demonstrations the model trains on (those not held out for validation, over every process):

- steps: BASE_STEPS, or more where the data is larger, so that each training demonstration is drawn into a batch
  DRAWS_PER_DEMONSTRATION times on average (rounded up to a multiple of ROUND_STEPS);
- warm-up: WARMUP_SHARE of the steps, at most MAX_WARMUP;
- validation: VALIDATIONS times over the steps, at most every MAX_VAL_EVERY steps.

The warm-up and the validation interval follow the steps whether those were given or scheduled. Patience is counted
in validations (`TrainConfig.patience`, not scheduled): its default is more than the validations of BASE_STEPS, so it
only cuts a longer run. No torch: the CLI and config.json's readers import it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from cnep.models.config import TrainConfig

log = logging.getLogger(__name__)

# The steps every open-loop result was measured at (docs/results.md: the demo, commitment, the paper's sets, Baxter).
BASE_STEPS = 4_000
# The largest data those were measured on (the 6-mode sets' 307 training demonstrations) drew each demonstration about
# 417 times in BASE_STEPS steps of 32 samples: larger data gets the steps that keep that many draws.
DRAWS_PER_DEMONSTRATION = 400
ROUND_STEPS = 100
WARMUP_SHARE, MAX_WARMUP = 0.5, 2_000
VALIDATIONS, MAX_VAL_EVERY = 8, 500
SCHEDULED = ("steps", "warmup_steps", "val_every")  # the TrainConfig fields the schedule fills when None


@dataclass(frozen=True)
class Schedule:
    """What the rule gave a training run: its input (`demonstrations`: training demonstrations, `batch_size`: samples
    per step over every process), the values it trains with and the names of those given rather than scheduled.
    config.json holds it under `training.schedule`."""

    demonstrations: int
    batch_size: int
    steps: int
    warmup_steps: int
    val_every: int
    given: tuple[str, ...]

    def to_dict(self) -> dict:
        return {
            "inputs": {"demonstrations": self.demonstrations, "batch_size": self.batch_size},
            "steps": self.steps,
            "warmup_steps": self.warmup_steps,
            "val_every": self.val_every,
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


def schedule_of(training: TrainConfig, demonstrations: int, world_size: int = 1) -> Schedule:
    """The schedule of `training` for `demonstrations` training demonstrations (every process's), `world_size`
    processes each drawing `training.batch_size` samples a step: its given values kept, the others the rule's."""
    batch = training.batch_size * world_size
    steps = training.steps if training.steps is not None else scheduled_steps(demonstrations, batch)
    warmup = training.warmup_steps if training.warmup_steps is not None else warmup_for(steps)
    val_every = training.val_every if training.val_every is not None else val_every_for(steps)
    given = tuple(name for name in SCHEDULED if getattr(training, name) is not None)
    if warmup >= steps:
        log.warning("a warm-up of %d steps in %d steps: the learning rate never reaches its peak", warmup, steps)
    return Schedule(demonstrations, batch, steps, warmup, val_every, given)


def scheduled(training: TrainConfig, demonstrations: int, world_size: int = 1) -> TrainConfig:
    """`training` with its unset schedule settings filled in (schedule_of); unchanged where all are set."""
    made = schedule_of(training, demonstrations, world_size)
    return replace(training, steps=made.steps, warmup_steps=made.warmup_steps, val_every=made.val_every)
