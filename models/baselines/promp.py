"""ProMP baseline: `movement_primitives.promp.ProMP`, imitated from the demonstrations, conditioned per point."""

from __future__ import annotations

import numpy as np

from cnep.models.baselines.base import check_demos, grid, require, resample

EM_ITERATIONS = 1000  # the library's default: the EM of `imitate` stops earlier when the weights settle
# Variance (in the data's units) added to every observation's: exact observations at neighbouring steps, each a
# via-point of the conditional before, leave a covariance too small to invert.
CONDITION_FLOOR = 1e-6


class ProMP:
    """`n_weights` radial basis functions per output dimension (the authors used 10/30/8 for uni/bi/multi), imitated
    by at most `iterations` EM iterations."""

    def __init__(self, n_weights: int = 10, iterations: int = EM_ITERATIONS) -> None:
        self.n_weights, self.iterations = n_weights, iterations

    def fit(self, demos: np.ndarray) -> ProMP:
        promp = require("movement_primitives.promp", "movement-primitives")
        demos = check_demos(demos)  # (N, T, dy)
        N, T, dy = demos.shape
        self.T = T
        self.promp = promp.ProMP(n_dims=dy, n_weights_per_dim=self.n_weights)
        self.promp.imitate(np.tile(grid(T), (N, 1)), demos, n_iter=self.iterations)
        return self

    def generate(
        self, obs_t: np.ndarray, obs_y: np.ndarray, query_t: np.ndarray, noise: np.ndarray | None = None
    ) -> np.ndarray:
        """The mean trajectory conditioned on each observation in turn, with the observations' variance `noise` (dy,)
        (None: 0) plus CONDITION_FLOOR."""
        obs_y = np.asarray(obs_y, dtype=np.float64).reshape(len(obs_t), -1)  # (n, dy)
        variance = np.zeros(obs_y.shape[1]) if noise is None else np.asarray(noise, dtype=np.float64)
        cov = np.diag(variance + CONDITION_FLOOR)  # (dy, dy)
        conditioned = self.promp
        for t, y in zip(obs_t, obs_y):
            conditioned = conditioned.condition_position(y, y_cov=cov, t=float(t), t_max=1.0)
        mean = conditioned.mean_trajectory(grid(self.T))  # (T, dy)
        return resample(mean, np.asarray(query_t, dtype=np.float64))
