"""The baselines in the closed loop, behind the CNEP's interface: ProMP, GMM-GMR and nearest-demonstration retrieval
(cnep.models.baselines), each a `runtime.conditioning.Network` inside a `runtime.Policy` that reads the camera with
the exported CNEP's feature graph and the state as the CNEP does.

The baselines see the features reduced by PCA: `components` principal components fitted on the training frames'
features (in the CNEP's normalised units), beside the 8 state values. A demonstration is its rows resampled to
a fixed number of steps over its phase (BASELINES). The policy conditions on its current observation alone (a
window of one, no anchor): `encode` gives the observation's reduced row, `decode` the method's trajectory
conditioned on it at its phase, and its prediction of the CNEP's predicted columns (one expert, gate 1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from cnep.models.baselines import GMMGMR, NearestDemo, ProMP
from cnep.models.baselines.base import Method, resample
from cnep.pipeline.errors import PipelineError
from cnep.recordings import read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES
from cnep.runtime import ConditioningPolicy, Policy
from cnep.runtime.exported import load_features
from cnep.runtime.manifest import read_manifest
from cnep.runtime.spans import span_indices
from cnep.runtime.spec import PolicySpec

PROMP_ITERATIONS = 30  # ProMP's EM iterations (each inverts a weight covariance per demonstration)
# name -> a new method and the steps its demonstrations are resampled to. GMM-GMR's Gaussians span a whole
# demonstration (steps x columns dimensions): more than a few hundred and their densities underflow to 0.
BASELINES = {
    "ProMP": (lambda: ProMP(n_weights=10, iterations=PROMP_ITERATIONS), 64),
    "GMM-GMR": (lambda: GMMGMR(n_components=4), 16),
    "Nearest": (NearestDemo, 64),
}
CURRENT_ONLY = ConditioningPolicy(window=1, anchors=0)


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
        if components > len(vt):  # at most one per feature and one per frame
            raise PipelineError(
                f"--pca {components}: the training frames' features have {len(vt)} principal components "
                f"({len(observed)} frames of {len(feature_at)} features); choose --pca {len(vt)} or fewer"
            )
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


def baseline_policy(name: str, cnep: Path, trajectories: list[Path], components: int, waypoints: int) -> Policy:
    """The baseline `name` (a BASELINES key) as a policy, fitted on the `trajectories` (MCAP) with the exported CNEP
    `cnep`'s normaliser, spec and feature graph, the features reduced to `components`."""
    spec = read_manifest(cnep).spec
    cols = span_indices(spec.columns.observed)
    demos = [_normalised_rows(spec, read_trajectory(path))[:, cols] for path in trajectories]
    reduction = Reduction.fit(spec, np.concatenate(demos), components)
    make, steps = BASELINES[name]
    grid = np.linspace(0.0, 1.0, steps)
    reduced = np.stack([resample(reduction(d), grid) for d in demos])  # (N, steps, k + rest)
    rest = [c for c in cols if c not in set(range(*spec.features))]
    predicted = np.array([components + rest.index(c) for c in span_indices(spec.columns.predicted)])
    network = BaselineNetwork(make().fit(reduced), reduction, predicted)
    one = replace(spec, n_experts=1)
    return Policy(network, one, load_features(cnep, threads=1), waypoints=waypoints, conditioning=CURRENT_ONLY)


def _normalised_rows(spec: PolicySpec, trajectory) -> np.ndarray:
    """A trajectory's model rows (T, width) as the policy builds them (features, then the state by `spec.state`),
    normalised with the CNEP's loc and scale."""
    data = trajectory.data
    rows = np.zeros((len(data), spec.columns.width), np.float64)
    a, b = spec.features
    f0, f1 = trajectory.blocks[BLOCK_FEATURES]
    rows[:, a:b] = data[:, f0:f1]
    state = data[:, f1:]  # the pose and the gripper after the features: runtime.spec.STATE_NAMES' order
    for (s0, s1), (r0, r1) in spec.state:
        rows[:, r0:r1] = state[:, s0:s1]
    return (rows - spec.columns.loc) / spec.columns.scale
