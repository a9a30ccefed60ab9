"""GMM-GMR baseline: a `gmr.GMM` over whole trajectories, conditioned on the observed time steps.

Each demonstration is one sample of dimension T * dy. With fewer demonstrations per component than
dimensions the EM covariances are singular; `ridge` adds `ridge * range**2 * I` to every covariance
after each M-step (EM with a covariance floor, like scikit-learn's `reg_covar`), where `range` is the
peak-to-peak range of the training data. `ridge=0` is the library's plain EM (what the authors ran).
Plain EM often leaves empty components (prior near 0, mean 0, covariance 0); when the library's
conditional puts its weight on them (with a ridge it hardly does), its prediction is 0 at every
unobserved step. Such outputs and non-finite ones are returned as NaN, which the evaluation counts as
failures.
"""

from __future__ import annotations

import numpy as np

from cnep.models.baselines.base import check_demos, require, resample

RIDGE = 1e-3  # default covariance ridge, as a fraction of the squared data range
EM_ITERATIONS = 100
EM_TOLERANCE = 1e-6  # stop when the means move less than this (relative to the data range)
EMPTY = 1e-12  # a component with a smaller prior holds no demonstration (plain EM leaves them far below)
EMPTY_WEIGHT = 1e-3  # a conditional giving empty components more weight than this is a failure


class GMMGMR:
    """`n_components` Gaussians (the authors used 10/20/6 for uni/bi/multi), seeded initialisation."""

    def __init__(self, n_components: int = 10, ridge: float = RIDGE, seed: int = 0) -> None:
        self.n_components, self.ridge, self.seed = n_components, ridge, seed

    def fit(self, demos: np.ndarray) -> GMMGMR:
        gmr = require("gmr", "gmr")
        demos = check_demos(demos)  # (N, T, dy)
        N, self.T, self.dy = demos.shape
        X = demos.reshape(N, -1)  # (N, T*dy), time-major: step k's outputs at k*dy .. k*dy+dy
        self.gmm = gmr.GMM(n_components=min(self.n_components, N), random_state=self.seed)
        if self.ridge == 0:
            self.gmm.from_samples(X, n_iter=EM_ITERATIONS)
            return self
        floor = self.ridge * np.ptp(X) ** 2 * np.eye(X.shape[1])  # (D, D)
        span = max(float(np.ptp(X)), 1e-12)
        for _ in range(EM_ITERATIONS):  # one library EM step at a time, then the ridge
            before = None if self.gmm.means is None else self.gmm.means.copy()
            self.gmm.from_samples(X, n_iter=1)
            self.gmm.covariances += floor
            if before is not None and np.abs(self.gmm.means - before).max() < EM_TOLERANCE * span:
                break
        return self

    def generate(
        self, obs_t: np.ndarray, obs_y: np.ndarray, query_t: np.ndarray, noise: np.ndarray | None = None
    ) -> np.ndarray:
        """Conditions on the demonstration steps nearest to `obs_t`, each observed with the variance `noise` (dy,)
        added to the components' (None: exactly); the GMR mean is returned."""
        obs_y = np.asarray(obs_y, dtype=np.float64).reshape(len(obs_t), self.dy)
        steps = np.rint(np.asarray(obs_t) * (self.T - 1)).astype(int)  # (n,)
        steps, first = np.unique(steps, return_index=True)  # a step observed twice is conditioned once
        indices = (steps[:, None] * self.dy + np.arange(self.dy)).ravel()  # (n*dy,)
        known = obs_y[first].ravel()  # (n*dy,)
        conditional = self._observed_with(noise).condition(indices, known)  # over the unobserved steps
        if conditional.priors[self.gmm.priors < EMPTY].sum() > EMPTY_WEIGHT:
            return np.full((len(query_t), self.dy), np.nan)  # the conditional picked empty components
        rest = conditional.priors @ conditional.means  # (T*dy - n*dy,): the GMR mean
        full = np.empty(self.T * self.dy)
        full[indices] = known
        full[np.setdiff1d(np.arange(self.T * self.dy), indices)] = rest
        return resample(full.reshape(self.T, self.dy), np.asarray(query_t, dtype=np.float64))

    def _observed_with(self, noise: np.ndarray | None):
        """The fitted GMM, or where `noise` (dy,) is given a copy whose components' covariances add that variance to
        every step's columns: the observed steps' is their observation noise (the conditional's mean and weights read
        no other)."""
        if noise is None:
            return self.gmm
        gmr = require("gmr", "gmr")
        covariances = self.gmm.covariances.copy()  # (K, T*dy, T*dy)
        at = np.arange(self.T * self.dy)
        covariances[:, at, at] += np.tile(np.asarray(noise, dtype=np.float64), self.T)  # a step's columns alike
        return gmr.GMM(self.gmm.n_components, self.gmm.priors, self.gmm.means, covariances)
