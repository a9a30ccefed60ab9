"""The paper's synthetic demonstration sets, regenerated from a seed.

Every set has disjoint train / validation / test demonstrations drawn from the same generator (the
authors' 4-mode validation reused training trajectories; we do not). Arrays are `(N, T, 1)` with one
mode label per demonstration; labels are for evaluation only and never reach training.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnep.models.errors import ConfigError


@dataclass(frozen=True)
class SyntheticSet:
    name: str
    train: np.ndarray  # (N, T, 1)
    train_modes: np.ndarray  # (N,)
    val: np.ndarray
    val_modes: np.ndarray
    test: np.ndarray
    test_modes: np.ndarray

    @property
    def n_modes(self) -> int:
        return int(self.train_modes.max()) + 1

    @property
    def steps(self) -> int:
        return self.train.shape[1]


def _unimodal(modes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = np.arange(100) / 100  # x in [0, 1)
    basis = np.stack([np.sin(5 * x), x**2, x, np.ones_like(x)])  # (4, T)
    a = np.array([0.2, 0.2, 0.01, -0.05]) + 0.02 * rng.standard_normal((len(modes), 4))  # (N, 4)
    return -(a @ basis)


def _bimodal(modes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = np.linspace(0, 1, 200)
    amp, freq, phase = np.array([1.5, 1.0]), np.array([1.0, 2.5]), np.array([0.0, np.pi / 2])
    offset = 0.05 * rng.standard_normal((len(modes), 1))
    return amp[modes, None] * np.sin(2 * np.pi * freq[modes, None] * x + phase[modes, None]) + offset


def _multimodal4(modes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = np.linspace(0, 1, 200)
    k = modes[:, None] + 1
    phi = rng.uniform(0, 0.05 * np.pi, (len(modes), 1))
    return (np.sin(np.pi * ((x + 0.2 * k) * k * np.pi / 2 + phi)) + 1) / 2


def _multimodal6(modes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    x = np.linspace(0, 1, 200)
    sigmoid = 2 / (1 + np.exp(-12 * (x - 0.5))) - 1
    u = 8 * (x - 0.5) ** 2 - 1
    shapes = np.stack([np.sin(2 * np.pi * x), np.cos(2 * np.pi * x), sigmoid, -sigmoid, u, -u])  # (6, T)
    return (
        shapes[modes] + 0.02 * rng.standard_normal((len(modes), 1)) + 0.01 * rng.standard_normal((len(modes), len(x)))
    )


# name -> (generator, number of modes, demonstrations per split: train, val, test)
SETS = {
    "unimodal": (_unimodal, 1, (24, 6, 6)),
    "bimodal": (_bimodal, 2, (128, 32, 32)),
    "multimodal": (_multimodal4, 4, (128, 32, 32)),
    "multimodal6": (_multimodal6, 6, (384, 96, 96)),
}


def make_set(name: str, seed: int = 0) -> SyntheticSet:
    """One of `SETS`, with modes alternating within each split."""
    if name not in SETS:
        raise ConfigError(f"Unknown synthetic set {name!r}; choose one of {sorted(SETS)}.")
    generate, n_modes, sizes = SETS[name]
    rng = np.random.default_rng(seed)
    splits = []
    for size in sizes:
        modes = np.arange(size) % n_modes
        splits += [generate(modes, rng)[..., None].astype(np.float32), modes]
    return SyntheticSet(name, *splits)
