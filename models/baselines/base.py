"""What every method of the comparison offers, and the helpers the baselines share."""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Protocol

import numpy as np

from cnep.models.errors import ConfigError

EXTRA = "baselines"  # the optional extra of pyproject.toml that installs the baselines' libraries


class Method(Protocol):
    """Fit on demonstrations, then generate from conditioning points."""

    def fit(self, demos: np.ndarray) -> Method:
        """demos: (N, T, dy), step k at time k / (T - 1)."""
        ...

    def generate(
        self, obs_t: np.ndarray, obs_y: np.ndarray, query_t: np.ndarray, noise: np.ndarray | None = None
    ) -> np.ndarray:
        """obs_t (n,) in [0, 1], obs_y (n, dy), query_t (m,) -> (m, dy); noise (dy,): the observations' variance per
        column (None: exact observations; a method without a noise model ignores it)."""
        ...


def require(module: str, package: str) -> ModuleType:
    """Import an optional library, or fail with a message naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ConfigError(
            f"This baseline needs the `{package}` package, which is not installed; install the optional "
            f"extra with `pip install .[{EXTRA}]` (or `pip install {package}`)."
        ) from exc


def check_demos(demos: np.ndarray) -> np.ndarray:
    """Validate `(N, T, dy)` demonstrations and return them as float64."""
    demos = np.asarray(demos, dtype=np.float64)
    if demos.ndim != 3 or demos.shape[0] < 1 or demos.shape[1] < 2:
        raise ConfigError(f"Demonstrations must be an (N, T, dy) array with N >= 1 and T >= 2, got {demos.shape}.")
    return demos


def grid(T: int) -> np.ndarray:
    """The demonstrations' times: (T,) from 0 to 1."""
    return np.arange(T) / (T - 1)


def resample(traj: np.ndarray, query_t: np.ndarray) -> np.ndarray:
    """A trajectory (T, dy) on `grid(T)` -> (m, dy) at `query_t`, linearly interpolated."""
    t = grid(len(traj))
    return np.stack([np.interp(query_t, t, traj[:, j]) for j in range(traj.shape[1])], axis=-1)
