"""Per-column standardisation fitted on the training trajectories, stored in the model's state.

Normalisation statistics travel with the weights (they are buffers of the model), so a checkpoint
can never be used with statistics from another data set.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from cnep.models.errors import ConfigError


class Normaliser(nn.Module):
    """`(x - loc) / scale` per column; constant columns get scale 1 so they map to 0, not to inf."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.register_buffer("loc", torch.zeros(width))
        self.register_buffer("scale", torch.ones(width))

    @torch.no_grad()
    def fit(self, trajectories: Sequence[np.ndarray]) -> Normaliser:
        rows = np.concatenate([np.asarray(t, dtype=np.float64) for t in trajectories], axis=0)
        if rows.shape[1] != self.loc.numel():
            raise ConfigError(f"Normaliser expects {self.loc.numel()} columns, got trajectories with {rows.shape[1]}.")
        with np.errstate(over="ignore", invalid="ignore"):  # reported below, naming the column
            std = rows.std(axis=0)
        if not np.isfinite(std).all():
            col = int(np.flatnonzero(~np.isfinite(std))[0])
            largest = np.abs(rows[:, col]).max()
            raise ConfigError(
                f"Column {col} holds values too large to normalise (largest magnitude {largest:.3g}); the "
                f"trajectories hold a value far outside the others."
            )
        self.loc.copy_(torch.from_numpy(rows.mean(axis=0)))
        self.scale.copy_(torch.from_numpy(np.where(std > 1e-8 * (1 + np.abs(rows).max(axis=0)), std, 1.0)))
        return self

    def normalise(self, x: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        return (x - self.loc[columns]) / self.scale[columns]

    def denormalise(self, x: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        return x * self.scale[columns] + self.loc[columns]
