"""The gripper command a two-state gripper executes, from the model's continuous gripper prediction.

A CNEP predicts the gripper as a continuous value (the recordings' unit: an opening in m, a command in
[0, 1], ...); a gripper that is either open or closed needs one of its two values. The demonstrations hold
those two values, `low` and `high`; `GripperCommand.from_demonstrations` finds them as the two clusters of the
demonstrations' gripper values (the medians of a 1-D two-means split), and which of them is closed (`closed`) as
the one the demonstrations do not start at: a demonstration starts with the gripper open, whichever way the
recordings count. The command is a threshold with hysteresis: it goes to `high` when the prediction rises above
`rise`, to `low` when it falls below `fall`, and holds between them, so a prediction hovering near the middle does
not make the gripper chatter. Both thresholds sit HYSTERESIS of the gap from the middle of the two values.

A recording's gripper is often the measured opening: closed on an object it reads the object's width, so the
closed value is the width of the objects the demonstrations held, and a gripper commanded to that width would not
squeeze. `is_closed(command)` says what a two-state gripper executes: close (with its own force) or open.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from cnep.runtime.errors import PolicyError

HYSTERESIS = 0.25  # each threshold's distance from the middle of the two values, as a fraction of their gap
LOW, HIGH = "low", "high"  # which of the two values closes the gripper
TWO_MEANS_ITERATIONS = 100  # at most; the split of one-dimensional values settles in a few


@dataclass(frozen=True)
class GripperCommand:
    """low, high: the gripper's two values (the recordings' unit, low <= high); rise, fall: the prediction above
    which the command goes to `high` and below which it goes to `low` (fall <= rise; between them it holds);
    closed: which of the two values is the closed gripper ("low" or "high")."""

    low: float
    high: float
    rise: float
    fall: float
    closed: str = LOW

    def __post_init__(self) -> None:
        values = (self.low, self.high, self.rise, self.fall)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise PolicyError(f"a gripper command needs four finite numbers, got {asdict(self)}")
        if self.closed not in (LOW, HIGH):
            raise PolicyError(f"a gripper command's closed value is {LOW!r} or {HIGH!r}, got {self.closed!r}")
        if not (self.low <= self.fall <= self.rise <= self.high):
            raise PolicyError(
                f"a gripper command needs low <= fall <= rise <= high, got low {self.low}, fall {self.fall}, "
                f"rise {self.rise}, high {self.high}"
            )

    @classmethod
    def from_levels(cls, low: float, high: float, closed: str = LOW) -> GripperCommand:
        """The command between the two values `low` < `high` (or one value, for a gripper that never moves), `closed`
        the one that closes the gripper."""
        middle, band = (low + high) / 2, HYSTERESIS * (high - low)
        return cls(float(low), float(high), float(middle + band), float(middle - band), closed)

    @classmethod
    def from_demonstrations(cls, values: np.ndarray, starts: np.ndarray | None = None) -> GripperCommand:
        """The command of the demonstrations' gripper values (any shape, the recordings' unit): their two values
        are the medians of the two clusters of a one-dimensional two-means split (one value if they never vary);
        starts: each demonstration's first gripper value, which are open: the other value closes (None, or as many
        starting at each: the lower one closes, as an opening reads)."""
        values = np.sort(np.asarray(values, dtype=np.float64).reshape(-1))
        if not len(values) or not np.isfinite(values).all():
            raise PolicyError(f"a gripper command needs finite gripper values, got {len(values)} value(s)")
        cut = len(values) // 2  # the first index of the high cluster
        split = (values[0] + values[-1]) / 2
        for _ in range(TWO_MEANS_ITERATIONS):
            cut = int(np.searchsorted(values, split, side="right"))
            if cut in (0, len(values)):  # one value throughout
                return cls.from_levels(float(values[0]), float(values[0]))
            new = (values[:cut].mean() + values[cut:].mean()) / 2
            if new == split:
                break
            split = new
        low, high = float(np.median(values[:cut])), float(np.median(values[cut:]))
        command = cls.from_levels(low, high)
        if starts is not None:
            nearest = [command.nearest(float(v)) for v in np.asarray(starts, dtype=np.float64).reshape(-1)]
            if nearest.count(low) > nearest.count(high):  # most start low: low is open
                command = cls.from_levels(low, high, closed=HIGH)
        return command

    def is_closed(self, command: float) -> bool:
        """Whether `command` (one of the two values) closes the gripper."""
        return command == (self.low if self.closed == LOW else self.high)

    def command(self, value: float, previous: float) -> float:
        """The command for the predicted gripper `value` after the command `previous` (`low` or `high`)."""
        if value > self.rise:
            return self.high
        if value < self.fall:
            return self.low
        return previous

    def nearest(self, value: float) -> float:
        """The one of the two values nearest `value` (the command that matches a gripper's state)."""
        return self.high if value - self.low > self.high - value else self.low

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> GripperCommand:
        """The command of `to_dict` (`closed` may be absent, as a command stored before it was has none: "low", the
        opening's convention)."""
        try:
            return cls(*(float(data[name]) for name in ("low", "high", "rise", "fall")), data.get("closed", LOW))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            if isinstance(exc, PolicyError):
                raise
            raise PolicyError(f"a gripper command needs low, high, rise and fall, got {data!r} ({exc})") from None
