"""Candidate weights for a choice made after training: the weights with the lowest validation error in each of `n`
equal parts of the steps where a run may keep weights (from `Trainer.keep_from` to the last step).

The best weights by validation error (what `Trainer` keeps) are one of them, those of the part they fall in; the
others are what the same rule keeps at other points of training. Where a closed loop exists to score them
(pipeline.sim.selection), it chooses among these by success on validation episodes: a lower error on the held-out
demonstrations is not always the policy that succeeds most in closed loop.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field


@dataclass
class Kept:
    """One candidate: the step it was validated at, its validation error (normalised units) and its state_dict."""

    step: int
    error: float
    state: dict


@dataclass
class Candidates:
    """The candidates of a run: n parts of the steps first .. last, each part's best validation (`Kept`) once it has
    one. `offer` every validation that may be kept (the Trainer's own conditions)."""

    n: int
    first: int
    last: int
    kept: dict[int, Kept] = field(default_factory=dict)

    def part(self, step: int) -> int:
        """The part (0 .. n - 1) that step falls in."""
        span = max(1, self.last - self.first + 1)
        return min(self.n - 1, max(0, step - self.first) * self.n // span)

    def offer(self, step: int, error: float, state: dict) -> None:
        """Keep a copy of `state` when `error` is below the kept one of its step's part (an equal one: the earlier
        stays, as the Trainer keeps its best)."""
        part = self.part(step)
        if part not in self.kept or error < self.kept[part].error:
            self.kept[part] = Kept(step, error, copy.deepcopy(state))

    def in_order(self) -> list[Kept]:
        """The kept candidates, earliest first."""
        return [self.kept[part] for part in sorted(self.kept)]

    def state_dict(self) -> dict:
        return {
            "n": self.n,
            "kept": {part: {"step": k.step, "error": k.error, "state": k.state} for part, k in self.kept.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        self.kept = {int(part): Kept(**kept) for part, kept in state["kept"].items()}
