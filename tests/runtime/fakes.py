"""A small numpy network and spec for the runtime's tests: no torch, no files."""

from __future__ import annotations

import numpy as np

from cnep.runtime import Columns, PolicySpec, TimeBase

FEATURES = 6  # width of the fake feature vector
WIDTH = FEATURES + 8  # model row: features | x y z qx qy qz qw gripper
LATENT = 5
EXPERTS = 3


class LinearNetwork:
    """encode: tanh of a linear map; gate: softmax of a linear map of r; experts: linear in [r, t]."""

    def __init__(self, obs_dim: int, query_dim: int, out_dim: int, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.W = rng.normal(size=(1 + obs_dim, LATENT)).astype(np.float32)
        self.G = (5 * rng.normal(size=(LATENT, EXPERTS))).astype(np.float32)
        self.E = rng.normal(size=(EXPERTS, LATENT + 1 + query_dim, out_dim)).astype(np.float32)
        self.encoded = 0  # rows encoded so far

    def encode(self, obs: np.ndarray) -> np.ndarray:
        self.encoded += len(obs)
        return np.tanh(obs @ self.W)  # (N, H)

    def decode(self, r: np.ndarray, query: np.ndarray):
        logits = r[0] @ self.G
        gate = np.exp(logits - logits.max())
        gate /= gate.sum()  # (d,)
        x = np.concatenate([np.repeat(r, len(query), axis=0), query], axis=1)  # (M, H + 1 + q)
        mean = np.einsum("mi,eio->emo", x, self.E)  # (d, M, dy)
        return gate.astype(np.float32), mean.astype(np.float32), np.full_like(mean, 0.1, dtype=np.float32)


TIME_BASE = TimeBase(2.0, 0.1)


def camera_spec(time_base: TimeBase | None = TIME_BASE) -> PolicySpec:
    """Observes the whole row, predicts x y z and the gripper; the features come first."""
    rng = np.random.default_rng(1)
    columns = Columns(
        observed=((0, WIDTH),),
        query=(),
        predicted=((FEATURES, FEATURES + 3), (WIDTH - 1, WIDTH)),
        loc=rng.normal(size=WIDTH).astype(np.float32),
        scale=rng.uniform(0.5, 2, size=WIDTH).astype(np.float32),
    )
    state = (((0, 7), (FEATURES, FEATURES + 7)), ((7, 8), (WIDTH - 1, WIDTH)))
    return PolicySpec(columns, EXPERTS, (0, FEATURES), state, time_base)


def camera_network(seed: int = 0) -> LinearNetwork:
    return LinearNetwork(WIDTH, 0, 4, seed)


def mean_colour_features(pixels: np.ndarray) -> np.ndarray:
    """(1, 224, 224, 3) uint8 -> (1, FEATURES): the mean of each colour channel and its square, scaled."""
    mean = pixels.reshape(len(pixels), -1, 3).mean(1) / 255.0  # (1, 3)
    return np.concatenate([mean, mean**2], axis=1).astype(np.float32)


class ScriptedNetwork(LinearNetwork):
    """LinearNetwork whose gate at the k-th decode is `gates[k]` (the last one after the script) and whose last
    predicted column is `last[k]`, normalised (every expert, every query)."""

    def __init__(self, gates, last=None, obs_dim: int = WIDTH, out_dim: int = 4) -> None:
        super().__init__(obs_dim, 0, out_dim)
        self.gates, self.last, self.decoded = np.asarray(gates, dtype=np.float32), last, 0

    def decode(self, r: np.ndarray, query: np.ndarray):
        _, mean, std = super().decode(r, query)
        k = self.decoded
        self.decoded += 1
        if self.last is not None:
            mean[:, :, -1] = self.last[min(k, len(self.last) - 1)]
        return self.gates[min(k, len(self.gates) - 1)].copy(), mean, std
