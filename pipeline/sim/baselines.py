"""The baselines in the closed loop, behind the CNEP's interface: ProMP, GMM-GMR and nearest-demonstration retrieval
(cnep.models.baselines), each a `runtime.conditioning.Network` (models.baselines.network) inside a `runtime.Policy`
that reads the camera with the exported CNEP's feature graph and the state as the CNEP does, fitted here on the
training trajectories.

The baselines see the features reduced by PCA: `components` principal components fitted on the training frames'
features (in the CNEP's normalised units), beside the 8 state values. A demonstration is its rows resampled to
a fixed number of steps over its phase (BASELINES). The policy conditions on its current observation alone (a
window of one, no anchor): `encode` gives the observation's reduced row, `decode` the method's trajectory
conditioned on it at its phase, and its prediction of the CNEP's predicted columns (one expert, gate 1).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from cnep.models.baselines import GMMGMR, NearestDemo, ProMP
from cnep.models.baselines.base import resample
from cnep.models.baselines.network import BaselineNetwork, Reduction
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


def baseline_policy(name: str, cnep: Path, trajectories: list[Path], components: int, waypoints: int) -> Policy:
    """The baseline `name` (a BASELINES key) as a policy, fitted on the `trajectories` (MCAP) with the exported CNEP
    `cnep`'s normaliser, spec and feature graph, the features reduced to `components`."""
    spec = read_manifest(cnep).spec
    cols = span_indices(spec.columns.observed)
    demos = [_normalised_rows(spec, read_trajectory(path))[:, cols] for path in trajectories]
    check_components(components, len(np.concatenate(demos)), spec.features[1] - spec.features[0])
    reduction = Reduction.fit(spec, np.concatenate(demos), components)
    make, steps = BASELINES[name]
    grid = np.linspace(0.0, 1.0, steps)
    reduced = np.stack([resample(reduction(d), grid) for d in demos])  # (N, steps, k + rest)
    rest = [c for c in cols if c not in set(range(*spec.features))]
    predicted = np.array([components + rest.index(c) for c in span_indices(spec.columns.predicted)])
    network = BaselineNetwork(make().fit(reduced), reduction, predicted)
    one = replace(spec, n_experts=1)
    return Policy(network, one, load_features(cnep, threads=1), waypoints=waypoints, conditioning=CURRENT_ONLY)


def check_components(components: int, frames: int, features: int) -> None:
    """PipelineError naming --pca unless `frames` training frames of `features` features have `components` principal
    components (at most one per feature and one per frame)."""
    most = min(frames, features)
    if components > most:
        raise PipelineError(
            f"--pca {components}: the training frames' features have {most} principal components ({frames} frames "
            f"of {features} features); choose --pca {most} or fewer"
        )


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
