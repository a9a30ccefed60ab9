"""The gripper command a two-state gripper executes, from the model's continuous gripper prediction.

A CNEP predicts the gripper as a continuous value (the recordings' unit: an opening in m, a command in
[0, 1], ...); a gripper that is either open or closed needs one of its two values. The demonstrations hold
those two values, `low` and `high` (which is open is the robot's convention); `GripperCommand.from_demonstrations`
finds them as the two clusters of the demonstrations' gripper values (the medians of a 1-D two-means split).
The command is a threshold with hysteresis: it goes to `high` when the prediction rises above `rise`, to `low`
when it falls below `fall`, and holds between them, so a prediction hovering near the middle does not make the
gripper chatter. Both thresholds sit HYSTERESIS of the gap from the middle of the two values.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from cnep.runtime.errors import PolicyError

HYSTERESIS = 0.25  # each threshold's distance from the middle of the two values, as a fraction of their gap
TWO_MEANS_ITERATIONS = 100  # at most; the split of one-dimensional values settles in a few


@dataclass(frozen=True)
class GripperCommand:
    """low, high: the gripper's two values (the recordings' unit, low <= high); rise, fall: the prediction above
    which the command goes to `high` and below which it goes to `low` (fall <= rise; between them it holds)."""

    low: float
    high: float
    rise: float
    fall: float

    def __post_init__(self) -> None:
        values = (self.low, self.high, self.rise, self.fall)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise PolicyError(f"a gripper command needs four finite numbers, got {asdict(self)}")
        if not (self.low <= self.fall <= self.rise <= self.high):
            raise PolicyError(
                f"a gripper command needs low <= fall <= rise <= high, got low {self.low}, fall {self.fall}, "
                f"rise {self.rise}, high {self.high}"
            )

    @classmethod
    def from_levels(cls, low: float, high: float) -> GripperCommand:
        """The command between the two values `low` < `high` (or one value, for a gripper that never moves)."""
        middle, band = (low + high) / 2, HYSTERESIS * (high - low)
        return cls(float(low), float(high), float(middle + band), float(middle - band))

    @classmethod
    def from_demonstrations(cls, values: np.ndarray) -> GripperCommand:
        """The command of the demonstrations' gripper values (any shape, the recordings' unit): their two values
        are the medians of the two clusters of a one-dimensional two-means split (one value if they never vary)."""
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
        return cls.from_levels(float(np.median(values[:cut])), float(np.median(values[cut:])))

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
        try:
            return cls(*(float(data[name]) for name in ("low", "high", "rise", "fall")))
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyError(f"a gripper command needs low, high, rise and fall, got {data!r} ({exc})") from None
