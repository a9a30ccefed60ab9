"""Tiny synthetic inputs for model tests."""

from __future__ import annotations

import numpy as np
import torch

from cnep.models.config import CNEPConfig, ColumnRoles


def tiny_config(n_experts: int = 3, obs_dim: int = 2, query_dim: int = 1, out_dim: int = 2) -> CNEPConfig:
    """A small model whose observed, query and predicted columns all differ."""
    width = obs_dim + query_dim + out_dim
    columns = ColumnRoles(
        width=width,
        observed=((0, obs_dim),),
        query=((obs_dim, obs_dim + query_dim),) if query_dim else (),
        predicted=((obs_dim + query_dim, width),),
    )
    return CNEPConfig(
        columns=columns, n_experts=n_experts, encoder_widths=(16, 8), expert_widths=(16, 16), time_frequencies=2
    )


def random_inputs(config: CNEPConfig, B: int = 4, N: int = 5, M: int = 6, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    lay = config.columns
    obs = torch.rand(B, N, 1 + lay.obs_dim, generator=g)
    query = torch.rand(B, M, 1 + lay.query_dim, generator=g)
    return obs, torch.ones(B, N, dtype=torch.bool), query


def two_mode_trajectories(n: int = 16, T: int = 50, seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """Half rise, half fall from a shared start: (T, 1) trajectories and their modes."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)
    modes = np.arange(n) % 2
    trajs = [((1 if k else -1) * np.sin(np.pi * t) + 0.02 * rng.standard_normal())[:, None] for k in modes]
    return [x.astype(np.float32) for x in trajs], modes


def feature_config(features: int = 6, components: int | None = 3, out_dim: int = 2) -> CNEPConfig:
    """A small model observing `features` columns it never predicts (as a camera's features), read as `components`
    principal components, and the `out_dim` columns after them, which it predicts."""
    width = features + out_dim
    columns = ColumnRoles(width=width, observed=((0, width),), predicted=((features, width),))
    return CNEPConfig(
        columns=columns,
        encoder_widths=(16, 16),
        expert_widths=(16, 16),
        time_frequencies=2,
        feature_components=components,
    )


def feature_trajectories(
    n: int = 6, T: int = 20, features: int = 6, out_dim: int = 2, seed: int = 0
) -> list[np.ndarray]:
    """(T, features + out_dim) trajectories whose features vary mostly along two directions, on scales from 0.01 to
    100 around different centres, and whose predicted columns follow the first direction."""
    rng = np.random.default_rng(seed)
    directions = rng.standard_normal((2, features))  # (2, features)
    scales, centres = np.logspace(-2, 2, features), rng.uniform(-5, 5, features)
    trajectories = []
    for _ in range(n):
        latent = rng.standard_normal((T, 2)) * [3.0, 1.0]  # (T, 2)
        values = centres + scales * (latent @ directions + 0.05 * rng.standard_normal((T, features)))
        predicted = latent[:, :1] + 0.1 * rng.standard_normal((T, out_dim))
        trajectories.append(np.concatenate([values, predicted], axis=1).astype(np.float32))
    return trajectories
