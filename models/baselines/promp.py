"""ProMP baseline: `movement_primitives.promp.ProMP`, learned from the demonstrations by the library's EM or by least
squares, conditioned on all observations at once."""

from __future__ import annotations

import numpy as np

from cnep.models.baselines.base import check_demos, grid, require, resample

EM_ITERATIONS = 1000  # the library's default: the EM of `imitate` stops earlier when the weights settle
# How the weights' Gaussian is learned: EM, the library's `imitate` (Lazaric & Ghavamzadeh's EM, whose every iteration
# works on (steps x dimensions)-square matrices per demonstration); LEAST_SQUARES, ProMP's own estimate (Paraschos et
# al.): each demonstration's weights by ridge regression on the basis, their mean and covariance across
# demonstrations, the observation variance the fits' residual.
EM, LEAST_SQUARES = "em", "least-squares"
RIDGE = 1e-6  # added to the basis' Gram matrix and to the weights' covariance (fewer demonstrations than weights)
# Variance (in the data's units) added to every observation's: exact observations at neighbouring steps, each a
# via-point of the conditional before, leave a covariance too small to invert.
CONDITION_FLOOR = 1e-6


class ProMP:
    """`n_weights` radial basis functions per output dimension (the authors used 10/30/8 for uni/bi/multi), learned
    by `estimator` (EM: at most `iterations` iterations; LEAST_SQUARES)."""

    def __init__(self, n_weights: int = 10, iterations: int = EM_ITERATIONS, estimator: str = EM) -> None:
        if estimator not in (EM, LEAST_SQUARES):
            raise ValueError(f"estimator must be {EM!r} or {LEAST_SQUARES!r}, got {estimator!r}")
        self.n_weights, self.iterations, self.estimator = n_weights, iterations, estimator

    def fit(self, demos: np.ndarray) -> ProMP:
        promp = require("movement_primitives.promp", "movement-primitives")
        demos = check_demos(demos)  # (N, T, dy)
        N, T, dy = demos.shape
        self.T = T
        self.promp = promp.ProMP(n_dims=dy, n_weights_per_dim=self.n_weights)
        if self.estimator == EM:
            self.promp.imitate(np.tile(grid(T), (N, 1)), demos, n_iter=self.iterations)
        else:
            self._least_squares(demos)
        return self

    def _least_squares(self, demos: np.ndarray) -> None:
        """The weights' Gaussian and the observation variance from `demos` (N, T, dy) by least squares."""
        N, T, dy = demos.shape
        phi = self.promp._rbfs_1d_sequence(grid(T))  # (W, T)
        gram = phi @ phi.T + RIDGE * np.eye(self.n_weights)
        weights = np.linalg.solve(gram, np.einsum("wt,ntd->wnd", phi, demos).reshape(self.n_weights, -1))
        weights = weights.reshape(self.n_weights, N, dy).transpose(1, 2, 0).reshape(N, dy * self.n_weights)
        self.promp.weight_mean = weights.mean(axis=0)  # dimension-major, as trajectory_from_weights reads them
        centred = weights - self.promp.weight_mean
        self.promp.weight_cov = centred.T @ centred / max(N - 1, 1) + RIDGE * np.eye(dy * self.n_weights)
        fitted = np.einsum("wt,nwd->ntd", phi, weights.reshape(N, dy, self.n_weights).transpose(0, 2, 1))
        self.promp.variance = float(np.mean((fitted - demos) ** 2))

    def generate(
        self, obs_t: np.ndarray, obs_y: np.ndarray, query_t: np.ndarray, noise: np.ndarray | None = None
    ) -> np.ndarray:
        """The mean trajectory conditioned on the observations, each with the variance `noise` (dy,) (None: 0) plus
        CONDITION_FLOOR: the weights' Gaussian conditioned on all of them at once (the library's `condition_position`
        on each in turn gives the same mean, but updates the whole weight covariance per observation)."""
        obs_y = np.asarray(obs_y, dtype=np.float64).reshape(len(obs_t), -1)  # (n, dy)
        n, dy = obs_y.shape
        variance = np.zeros(dy) if noise is None else np.asarray(noise, dtype=np.float64)
        basis = np.stack([self.promp._rbfs_1d_point(float(t), 1.0) for t in obs_t])  # (n, W)
        psi = np.kron(np.eye(dy), basis.T)  # (dy*W, dy*n): the weights (dimension-major) -> the observations
        cov, mean = self.promp.weight_cov, self.promp.weight_mean  # (dy*W, dy*W), (dy*W,)
        gram = psi.T @ cov @ psi + np.kron(np.diag(variance + CONDITION_FLOOR), np.eye(n))  # (dy*n, dy*n)
        residual = obs_y.T.reshape(-1) - psi.T @ mean  # (dy*n,): dimension-major, as psi's columns
        weights = mean + cov @ psi @ np.linalg.solve(gram, residual)  # (dy*W,)
        path = self.promp.trajectory_from_weights(grid(self.T), weights)  # (T, dy)
        return resample(path, np.asarray(query_t, dtype=np.float64))
