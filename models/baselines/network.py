"""A baseline as the runtime's `Network` (runtime.conditioning), so that a `runtime.Policy` runs it in a loop as it
runs a CNEP, through the same conditioning set: `Reduction` (the observed columns as the baselines see them: the
features' principal components, then the other observed columns) and `BaselineNetwork` (a fitted method conditioned on
the observations of the policy's conditioning set, at their phases, predicting the CNEP's predicted columns with one
expert).

The conditioner (runtime.conditioning.Conditioner) keeps the mean of its set's encodings, which is all a CNEP's
decoder reads. A baseline needs the observations themselves, so `BaselineNetwork.encode` files each observation under
its control step: the encoding is `slots` blocks of [1, t, reduced row], the observation's block filled and the others
0. The mean over the set then holds, in each occupied block, count / n times the mean of the observations of that
step (count: 1, or more where the phase stops at 1 after the motion's end), and `decode` divides the count back out:
the method is conditioned on exactly the observations of the set, whichever anchors and window the policy has.
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

    @property
    def width(self) -> int:
        """Columns of a reduced row: the components, then the other observed columns."""
        return self.basis.shape[1] + len(self.rest_at)

    def __call__(self, observed: np.ndarray) -> np.ndarray:
        """Observed rows (N, obs_dim) -> (N, k + rest)."""
        components = (observed[:, self.feature_at] - self.mean) @ self.basis
        return np.concatenate([components, observed[:, self.rest_at]], axis=1)


class BaselineNetwork:
    """A method fitted on reduced rows as a `Network` (module docstring).

    predicted: where the CNEP's predicted columns sit in a reduced row; slots: the control steps of the motion's phase
    (an observation at phase t is filed under step round(t * (slots - 1))); noise (k + rest,): the variance of the
    observations in a reduced row's units, which the method conditions with (None: exact).
    """

    def __init__(
        self,
        method: Method,
        reduction: Reduction,
        predicted: np.ndarray,
        slots: int,
        noise: np.ndarray | None = None,
    ) -> None:
        if slots < 2:
            raise ValueError(f"a baseline's phase needs at least 2 control steps, got {slots}")
        self.method, self.reduction, self.predicted, self.slots, self.noise = method, reduction, predicted, slots, noise
        self._block = 2 + reduction.width  # [1, t, reduced row]

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, observed columns] (N, 1 + obs_dim) -> each row's [1, t, reduced row] in its step's block, 0 elsewhere
        (N, slots * (2 + k + rest))."""
        n = len(obs)
        t = np.clip(obs[:, 0].astype(np.float64), 0.0, 1.0)  # (N,)
        step = np.rint(t * (self.slots - 1)).astype(int)  # (N,)
        blocks = np.zeros((n, self.slots, self._block), np.float32)  # (N, slots, 2 + k + rest)
        blocks[np.arange(n), step, 0] = 1.0
        blocks[np.arange(n), step, 1] = t
        blocks[np.arange(n), step, 2:] = self.reduction(obs[:, 1:].astype(np.float64))
        return blocks.reshape(n, -1)

    def observations(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The observations a mean of encodings r (1, H) holds: their phases (n,) and reduced rows (n, k + rest), in
        the order of their steps (those of one step as their mean)."""
        blocks = r.reshape(self.slots, self._block).astype(np.float64)  # (slots, 2 + k + rest)
        held = blocks[blocks[:, 0] > 0]  # (n, 2 + k + rest): a step without an observation holds 0 exactly
        return held[:, 1] / held[:, 0], held[:, 2:] / held[:, :1]

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The method conditioned on the observations r holds -> gate (1,), mean and std (1, M, dy) at query[:, 0]."""
        t, rows = self.observations(r)
        path = self.method.generate(t, rows, query[:, 0].astype(np.float64), noise=self.noise)
        mean = np.nan_to_num(path[:, self.predicted])[None].astype(np.float32)
        return np.ones(1, np.float32), mean, np.full_like(mean, 1e-3)


class ReducedNetwork:
    """A network trained on reduced rows (a CNEP on the principal components the baselines see) as a `Network` of the
    full rows: its encoder reads an observation reduced by `reduction` and normalised by its own statistics (`inner`,
    a runtime.conditioning.Columns of a reduced row), and its predictions of the reduced row's `predicted` columns
    come back in the full row's normalised units (a reduced row keeps the full row's normalised values outside the
    features)."""

    def __init__(self, network, reduction: Reduction, inner, predicted: np.ndarray) -> None:
        self.network, self.reduction = network, reduction
        self._loc, self._scale = inner.loc.astype(np.float64), inner.scale.astype(np.float64)  # (k + rest,)
        self._out_loc, self._out_scale = inner.loc[predicted], inner.scale[predicted]  # (dy,)

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, observed columns] (N, 1 + obs_dim) -> the network's encodings of [t, reduced row normalised] (N, H)."""
        reduced = (self.reduction(obs[:, 1:].astype(np.float64)) - self._loc) / self._scale  # (N, k + rest)
        return self.network.encode(np.concatenate([obs[:, :1], reduced], axis=1).astype(np.float32))

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The network's gate (d,), mean and std (d, M, dy), in the full row's normalised units."""
        gate, mean, std = self.network.decode(r, query)
        mean = (mean * self._out_scale + self._out_loc).astype(np.float32)
        return gate, mean, (std * self._out_scale).astype(np.float32)
