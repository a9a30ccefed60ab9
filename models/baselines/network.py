"""A baseline as the runtime's `Network` (runtime.conditioning), so that a `runtime.Policy` runs it in a loop as it
runs a CNEP: `Reduction` (the observed columns as the baselines see them: the features' principal components, then
the other observed columns) and `BaselineNetwork` (a fitted method conditioned on the current reduced row, at its
phase, predicting the CNEP's predicted columns with one expert).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnep.models.baselines.base import Method
from cnep.runtime.spans import span_indices
from cnep.runtime.spec import PolicySpec


@dataclass(frozen=True)
class Reduction:
    """The observed columns (normalised) as the baselines see them: the features' principal components, then the
    other observed columns. feature_at, rest_at: where the features and the others sit in an observed row;
    mean (F,), basis (F, k): the PCA."""

    feature_at: np.ndarray
    rest_at: np.ndarray
    mean: np.ndarray
    basis: np.ndarray

    @classmethod
    def fit(cls, spec: PolicySpec, observed: np.ndarray, components: int) -> Reduction:
        """The PCA of the features of `observed` (N, obs_dim) rows, normalised, for the CNEP's `spec`."""
        features = set(range(*spec.features))
        cols = span_indices(spec.columns.observed)
        feature_at = np.array([i for i, c in enumerate(cols) if c in features])
        rest_at = np.array([i for i, c in enumerate(cols) if c not in features])
        mean = observed[:, feature_at].mean(axis=0)
        _, _, vt = np.linalg.svd(observed[:, feature_at] - mean, full_matrices=False)
        return cls(feature_at, rest_at, mean, vt[:components].T)

    def __call__(self, observed: np.ndarray) -> np.ndarray:
        """Observed rows (N, obs_dim) -> (N, k + rest)."""
        components = (observed[:, self.feature_at] - self.mean) @ self.basis
        return np.concatenate([components, observed[:, self.rest_at]], axis=1)


class BaselineNetwork:
    """A method fitted on reduced rows as a `Network` (module docstring); `predicted`: where the CNEP's predicted
    columns sit in a reduced row."""

    def __init__(self, method: Method, reduction: Reduction, predicted: np.ndarray) -> None:
        self.method, self.reduction, self.predicted = method, reduction, predicted

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, observed columns] (N, 1 + obs_dim) -> [t, reduced row] (N, 1 + k + rest)."""
        return np.concatenate([obs[:, :1], self.reduction(obs[:, 1:])], axis=1).astype(np.float32)

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The method conditioned on r's row at r's phase -> gate (1,), mean and std (1, M, dy) at query[:, 0]."""
        t = np.clip(r[:, 0].astype(np.float64), 0.0, 1.0)
        path = self.method.generate(t, r[:, 1:].astype(np.float64), query[:, 0].astype(np.float64))
        mean = np.nan_to_num(path[:, self.predicted])[None].astype(np.float32)
        return np.ones(1, np.float32), mean, np.full_like(mean, 1e-3)
