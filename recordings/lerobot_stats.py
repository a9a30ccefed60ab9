"""The statistics a LeRobot dataset carries per feature (meta/stats.json, and each episode's in meta/episodes).

For every feature: `min`, `max`, `mean`, `std` (population), `count` (1,) and the quantiles `q01` ... `q99`
(`lerobot_layout.QUANTILES`), as LeRobot's policies read them to normalise their inputs and outputs:

- a vector feature, values (N, D): each entry's statistics over the N steps, shape (D,); a scalar column is D = 1;
- a camera, frames (H, W, 3) uint8 RGB: each colour channel's over every pixel of every frame, scaled to [0, 1] as
  LeRobot feeds images, shape (3, 1, 1); `count` is the number of frames.

Quantiles are exact: numpy's linear interpolation between the sorted values (for a camera, read from the
channel's 256-level histogram, which holds the same sorted values).
"""

from __future__ import annotations

import numpy as np

from cnep.recordings.lerobot_layout import QUANTILES

LEVELS = 256  # the values a uint8 pixel takes


def quantile_keys() -> list[str]:
    """`q01`, `q10`, ...: the keys of QUANTILES."""
    return [f"q{round(q * 100):02d}" for q in QUANTILES]


def vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """The statistics of values (N, D) (or (N,), taken as D = 1), each entry's, shape (D,); count (1,). min and max
    keep the values' type (an index column's are integers, as LeRobot's are), the others are float64."""
    values = np.asarray(values).reshape(len(values), -1)  # (N, D)
    real = values.astype(np.float64)
    stats = {
        "min": values.min(axis=0),
        "max": values.max(axis=0),
        "mean": real.mean(axis=0),
        "std": real.std(axis=0),
        "count": np.array([len(values)]),
    }
    quantiles = np.quantile(real, QUANTILES, axis=0)  # (Q, D)
    return stats | dict(zip(quantile_keys(), quantiles))


class ImageStats:
    """The per-channel statistics of RGB frames, kept as one 256-level histogram per channel (frames added one by one,
    histograms of several episodes summed: `merged`)."""

    def __init__(self) -> None:
        self.histograms = np.zeros((3, LEVELS), dtype=np.int64)  # (channel, level) pixel counts
        self.frames = 0

    def add(self, rgb: np.ndarray) -> None:
        """Count the pixels of one frame (H, W, 3) uint8 RGB."""
        for channel in range(3):
            self.histograms[channel] += np.bincount(rgb[..., channel].reshape(-1), minlength=LEVELS)
        self.frames += 1

    @classmethod
    def merged(cls, parts: list[ImageStats]) -> ImageStats:
        """The statistics of every frame of `parts` together."""
        whole = cls()
        for part in parts:
            whole.histograms += part.histograms
            whole.frames += part.frames
        return whole

    def stats(self) -> dict[str, np.ndarray]:
        """Each channel's statistics in [0, 1], shape (3, 1, 1); count (1,): the frames."""
        levels = np.arange(LEVELS, dtype=np.float64) / (LEVELS - 1)  # (256,) a level's value in [0, 1]
        counts = self.histograms.astype(np.float64)  # (3, 256)
        pixels = counts.sum(axis=1)  # (3,)
        mean = counts @ levels / pixels
        present = self.histograms > 0
        stats = {
            "min": levels[present.argmax(axis=1)],
            "max": levels[LEVELS - 1 - present[:, ::-1].argmax(axis=1)],
            "mean": mean,
            "std": np.sqrt(np.maximum(counts @ levels**2 / pixels - mean**2, 0.0)),
        }
        stats |= dict(zip(quantile_keys(), (self._quantile(q, levels) for q in QUANTILES)))
        return {k: v.reshape(3, 1, 1) for k, v in stats.items()} | {"count": np.array([self.frames])}

    def _quantile(self, q: float, levels: np.ndarray) -> np.ndarray:
        """Each channel's q-quantile (3,): linear between the sorted pixel values at q * (n - 1), as np.quantile."""
        cumulative = self.histograms.cumsum(axis=1)  # (3, 256): pixels at or below each level
        position = q * (cumulative[:, -1] - 1)  # (3,)
        below, above = np.floor(position).astype(np.int64), np.ceil(position).astype(np.int64)
        value_at = [
            [levels[np.searchsorted(cumulative[c], k, side="right")] for k in (below[c], above[c])] for c in range(3)
        ]
        low, high = np.array(value_at).T  # (3,) each
        return low + (position - below) * (high - low)
