"""What chooses settings in the closed loop, kept apart from what is reported: the validation episodes' seeds, and how
many candidate checkpoints and episodes choose each trained model (`SelectionSettings`, pipeline.sim.selection).

Episode seeds fall in three ranges, none shared:

- reported: `--episode-seed` .. `--episode-seed + --episodes - 1`, anywhere outside the validation range (the
  tables, `cnep sim` and `cnep sim eval`; `check_reported` refuses an overlap);
- validation: VALIDATION_SEED_OFFSET on, VALIDATION_SEEDS of them: the episodes that choose a run's kept checkpoint,
  never reported;
- demonstrations: sim.task.DEMO_SEED_OFFSET on, where the validation range ends (sim.task.demonstration_seed).

Importable without torch, MuJoCo or Gymnasium: the CLI checks a user's seeds before any stage loads.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnep.models.config import setting
from cnep.pipeline.errors import PipelineError

VALIDATION_SEED_OFFSET = 900_000  # the first validation episode's seed
VALIDATION_SEEDS = 100_000  # validation seeds reserved: up to the demonstrations' (sim.task.DEMO_SEED_OFFSET)
VALIDATION_RANGE = range(VALIDATION_SEED_OFFSET, VALIDATION_SEED_OFFSET + VALIDATION_SEEDS)


def validation_seeds(episodes: int) -> range:
    """The seeds of `episodes` validation episodes per condition: the first ones of VALIDATION_RANGE, the same for
    every candidate, model and training seed."""
    return VALIDATION_RANGE[:episodes]


def check_reported(first: int, episodes: int) -> None:
    """PipelineError when the reported episode seeds `first` .. `first + episodes - 1` meet VALIDATION_RANGE."""
    last = first + episodes - 1
    if first <= VALIDATION_RANGE[-1] and last >= VALIDATION_RANGE[0]:
        raise PipelineError(
            f"--episode-seed {first} and --episodes {episodes} give episode seeds {first} to {last}, which meet the "
            f"validation seeds ({VALIDATION_RANGE[0]} to {VALIDATION_RANGE[-1]}: they choose the kept checkpoints and "
            f"are never reported); choose seeds below {VALIDATION_RANGE[0]} or above {VALIDATION_RANGE[-1]}"
        )


def seeds_record(first: int, episodes: int, validation: range | None) -> dict:
    """What a summary says of its seeds: the `reported` episodes' first and last seed, the `validation` seeds that
    chose its settings (None: none did), and the range reserved for validation, which no reported seed meets."""

    def span(seeds: range) -> dict:
        return {"first": seeds[0], "last": seeds[-1]}

    return {
        "reported": span(range(first, first + episodes)),
        "validation": span(validation) if validation else None,
        "validation_range": span(VALIDATION_RANGE),
    }


@dataclass(frozen=True)
class SelectionSettings:
    """How `cnep sim` chooses the checkpoint it keeps of each trained model (pipeline.sim.selection): `candidates`
    checkpoints of the run (`cnep train --candidates`), each run for `selection_episodes` validation episodes per
    condition, online."""

    candidates: int = setting(
        3,
        "checkpoints of each training run the closed loop chooses from (as `cnep train --candidates` keeps them): the "
        "one that succeeds most in validation episodes is kept (ties: the lower validation error, then the later "
        "step); 1: the lowest validation error, as `cnep train` keeps it, with no validation episodes",
    )
    selection_episodes: int = setting(
        4,
        f"validation episodes of each candidate per condition (online protocol), on the episode seeds from "
        f"{VALIDATION_SEED_OFFSET} on, which are never reported",
    )

    def __post_init__(self) -> None:
        if self.candidates < 1 or not 1 <= self.selection_episodes <= VALIDATION_SEEDS:
            raise PipelineError(
                f"candidates must be >= 1 and selection_episodes from 1 to {VALIDATION_SEEDS}, got {self.candidates} "
                f"and {self.selection_episodes}"
            )

    @property
    def selects(self) -> bool:
        """Whether there is a choice to make: more than one candidate."""
        return self.candidates > 1
