"""Nearest-demonstration lookup: return the training demonstration closest to the conditioning points."""

from __future__ import annotations

import numpy as np

from cnep.models.baselines.base import check_demos, grid, resample


class NearestDemo:
    """The demonstration with the smallest squared distance to the conditioning points (interpolated in time)."""

    def fit(self, demos: np.ndarray) -> NearestDemo:
        self.demos = check_demos(demos)  # (N, T, dy)
        return self

    def nearest(self, obs_t: np.ndarray, obs_y: np.ndarray) -> int:
        """Index of the demonstration closest to the points obs_t (n,), obs_y (n, dy)."""
        N, T, dy = self.demos.shape
        t = grid(T)
        at_obs = np.stack([[np.interp(obs_t, t, d[:, j]) for j in range(dy)] for d in self.demos])  # (N, dy, n)
        dist = ((at_obs - np.asarray(obs_y, dtype=np.float64).reshape(len(obs_t), dy).T) ** 2).sum((1, 2))  # (N,)
        return int(dist.argmin())

    def generate(
        self, obs_t: np.ndarray, obs_y: np.ndarray, query_t: np.ndarray, noise: np.ndarray | None = None
    ) -> np.ndarray:
        """The nearest demonstration at `query_t` (noise: unused, every column's distance counts alike)."""
        return resample(self.demos[self.nearest(obs_t, obs_y)], np.asarray(query_t, dtype=np.float64))
