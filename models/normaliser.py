"""Per-column standardisation fitted on the training trajectories, stored in the model's state.

Normalisation statistics travel with the weights (they are buffers of the model), so a checkpoint
can never be used with statistics from another data set. They are fitted from `Moments`: each
trajectory's row count, column means and sums of squared deviations in float64, combined pairwise
(Chan, Golub and LeVeque's update), so that files read one at a time, or shares of them on several
processes, give the statistics of all their rows without ever holding them together. Where a model projects some
columns onto their principal components (models.projection), the moments carry those columns' scatter matrix too,
combined by the same update; only then, as it grows with the square of their number.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from cnep.models.errors import ConfigError


@dataclass(frozen=True)
class Moments:
    """Per-column statistics of `count` rows: mean, sum of squared deviations from it (m2) and largest magnitude,
    each (C,) float64; on the columns `co`, the scatter matrix (len(co), len(co)) float64: the sum over the rows of
    the outer product of their deviations from the mean (none where `co` is empty)."""

    count: int
    mean: np.ndarray
    m2: np.ndarray
    largest: np.ndarray
    co: tuple[int, ...] = ()
    scatter: np.ndarray | None = None

    @classmethod
    def of(cls, rows: np.ndarray, co: Sequence[int] = ()) -> Moments:
        """The moments of (T, C) `rows` (any float dtype; computed in float64), with the scatter matrix of columns
        `co`."""
        x = np.asarray(rows, dtype=np.float64)  # (T, C)
        mean = x.mean(axis=0)  # (C,)
        with np.errstate(over="ignore", invalid="ignore"):  # reported by `Normaliser.fit_moments`, naming the column
            m2 = ((x - mean) ** 2).sum(axis=0)
            deviations = x[:, list(co)] - mean[list(co)]  # (T, len(co))
            scatter = deviations.T @ deviations if co else None  # (len(co), len(co))
        return cls(len(x), mean, m2, np.abs(x).max(axis=0, initial=0.0), tuple(co), scatter)

    def __add__(self, other: Moments) -> Moments:
        """The moments of both sets of rows together."""
        if other.co != self.co:
            raise ConfigError("Moments carrying the scatter matrices of different columns cannot be combined.")
        if other.count == 0:
            return self
        if self.count == 0:
            return other
        n = self.count + other.count
        delta = other.mean - self.mean  # (C,)
        weight = self.count * other.count / n
        with np.errstate(over="ignore", invalid="ignore"):
            m2 = self.m2 + other.m2 + delta**2 * weight
            d = delta[list(self.co)]  # (len(co),)
            scatter = self.scatter + other.scatter + np.outer(d, d) * weight if self.co else None
        mean = self.mean + delta * (other.count / n)
        return Moments(n, mean, m2, np.maximum(self.largest, other.largest), self.co, scatter)

    @staticmethod
    def total(parts: Iterable[Moments]) -> Moments:
        """The moments of every part's rows, combined in the order given."""
        combined = None
        for part in parts:
            combined = part if combined is None else combined + part
        if combined is None:
            raise ConfigError("Normaliser needs at least one trajectory to fit on, got none.")
        return combined


class Normaliser(nn.Module):
    """`(x - loc) / scale` per column; constant columns get scale 1 so they map to 0, not to inf."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.register_buffer("loc", torch.zeros(width))
        self.register_buffer("scale", torch.ones(width))

    @torch.no_grad()
    def fit(self, trajectories: Sequence[np.ndarray]) -> Normaliser:
        """Fitted on every row of (T_i, C) `trajectories`."""
        return self.fit_moments(Moments.total(Moments.of(t) for t in trajectories))

    @torch.no_grad()
    def fit_moments(self, moments: Moments) -> Normaliser:
        """Fitted on the rows `moments` describe: their mean, and their standard deviation where it is above the
        columns' rounding noise (else 1)."""
        if moments.mean.shape != (self.loc.numel(),):
            raise ConfigError(
                f"Normaliser expects {self.loc.numel()} columns, got trajectories with {moments.mean.shape[-1]}."
            )
        with np.errstate(over="ignore", invalid="ignore"):
            std = np.sqrt(moments.m2 / moments.count)
        if not np.isfinite(std).all():
            col = int(np.flatnonzero(~np.isfinite(std))[0])
            raise ConfigError(
                f"Column {col} holds values too large to normalise (largest magnitude {moments.largest[col]:.3g}); "
                f"the trajectories hold a value far outside the others."
            )
        self.loc.copy_(torch.from_numpy(moments.mean))
        self.scale.copy_(torch.from_numpy(np.where(std > 1e-8 * (1 + moments.largest), std, 1.0)))
        return self

    def normalise(self, x: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        return (x - self.loc[columns]) / self.scale[columns]

    def denormalise(self, x: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        return x * self.scale[columns] + self.loc[columns]
