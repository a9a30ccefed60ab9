"""The time base: seconds since the episode began -> the model's phase t in [0, 1].

The model was trained with t = i / (T - 1) over each demonstration, so t = 1 is the demonstration's last
step. A robot knows only the seconds since its episode began; the time base maps them with the median
duration of the training demonstrations (first to last step): t = seconds / duration_s, clamped to [0, 1].
A run slower than the demonstrations reaches t = 1 before its motion ends (and holds it there), a faster
one ends before t = 1. `period_s`, the demonstrations' median step period, spaces the predicted waypoints
and stands in for the time when an observation carries none (step k is at k * period_s).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from cnep.runtime.errors import PolicyError


@dataclass(frozen=True)
class TimeBase:
    """duration_s: the episode's length in seconds (t = 1 there); period_s: seconds between two steps."""

    duration_s: float
    period_s: float

    def __post_init__(self) -> None:
        for name in ("duration_s", "period_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise PolicyError(f"TimeBase.{name} must be a finite number of seconds > 0, got {value!r}.")
        if self.period_s > self.duration_s:
            raise PolicyError(
                f"TimeBase.period_s ({self.period_s} s) is longer than the episode (duration_s {self.duration_s} s)."
            )

    @classmethod
    def from_demonstrations(cls, durations_s: Sequence[float], steps: Sequence[int]) -> TimeBase:
        """The median duration (s) and the median step period of demonstrations of `steps` (>= 2) steps each."""
        durations, counts = np.asarray(durations_s, dtype=np.float64), np.asarray(steps, dtype=np.float64)
        if not len(durations) or durations.shape != counts.shape or (counts < 2).any():
            raise PolicyError(
                f"a time base needs demonstrations of at least 2 steps each, got durations {list(durations_s)} "
                f"and steps {list(steps)}"
            )
        return cls(float(np.median(durations)), float(np.median(durations / (counts - 1))))

    @classmethod
    def parse(cls, text: str) -> TimeBase:
        """A time base written `DURATION_S,PERIOD_S` (e.g. `3.9,0.1`), as `cnep export --time-base` takes it."""
        try:
            duration_s, period_s = (float(part) for part in text.split(","))
        except ValueError:
            raise PolicyError(
                f"a time base is written DURATION_S,PERIOD_S (the episode's length and the step period in seconds, "
                f"e.g. 3.9,0.1), got {text!r}"
            ) from None
        return cls(duration_s, period_s)

    def phase(self, seconds: float) -> float:
        """The model's t of `seconds` since the episode began: seconds / duration_s, clamped to [0, 1]."""
        return min(max(seconds / self.duration_s, 0.0), 1.0)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TimeBase:
        try:
            return cls(float(data["duration_s"]), float(data["period_s"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyError(f"a time base needs duration_s and period_s in seconds, got {data!r} ({exc})") from None
