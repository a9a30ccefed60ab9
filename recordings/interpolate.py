"""Resampling pose and gripper at other times (frames and poses arrive at different rates).

Position and gripper are interpolated linearly in time; orientation by spherical linear
interpolation (slerp) between the two neighbouring quaternions, along the shorter arc. Query times
must lie inside [t_src[0], t_src[-1]]: nothing is extrapolated.
"""

from __future__ import annotations

import numpy as np

from cnep.recordings.errors import RecordingError


def _bracket(t_src: np.ndarray, t_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index i of the left neighbour (t_src[i] <= t < t_src[i+1]) and the fraction in [0, 1]."""
    if t_query.size and (t_query.min() < t_src[0] or t_query.max() > t_src[-1]):
        raise RecordingError(
            f"query times [{t_query.min()}, {t_query.max()}] ns reach outside the samples [{t_src[0]}, {t_src[-1]}] ns"
        )
    i = np.clip(np.searchsorted(t_src, t_query, side="right") - 1, 0, max(len(t_src) - 2, 0))  # (Q,)
    if len(t_src) == 1:
        return i, np.zeros(t_query.shape)
    span = (t_src[i + 1] - t_src[i]).astype(np.float64)  # (Q,)
    frac = (t_query - t_src[i]).astype(np.float64) / span  # (Q,)
    return i, np.clip(frac, 0.0, 1.0)


def interpolate_linear(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """values (N, ...) sampled at int64 ns times t_src (N,) -> (Q, ...) at t_query (Q,), linearly."""
    i, frac = _bracket(t_src, t_query)
    if len(t_src) == 1:
        return np.repeat(values[:1], len(t_query), axis=0)
    frac = frac.reshape(frac.shape + (1,) * (values.ndim - 1))
    return values[i] * (1.0 - frac) + values[i + 1] * frac


def slerp(t_src: np.ndarray, quats: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Unit quaternions xyzw (N, 4) at ns times t_src (N,) -> (Q, 4) at t_query by slerp."""
    q = quats / np.linalg.norm(quats, axis=1, keepdims=True)  # (N, 4)
    i, frac = _bracket(t_src, t_query)
    if len(t_src) == 1:
        return np.repeat(q[:1], len(t_query), axis=0)
    q0, q1 = q[i], q[i + 1]  # (Q, 4)
    dot = np.sum(q0 * q1, axis=1)  # (Q,)
    q1 = np.where(dot[:, None] < 0, -q1, q1)  # q and -q are the same rotation: take the shorter arc
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))  # (Q,)
    near = theta < 1e-6  # nearly identical: fall back to (normalised) linear interpolation
    sin_theta = np.where(near, 1.0, np.sin(theta))
    w0 = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * theta) / sin_theta)  # (Q,)
    w1 = np.where(near, frac, np.sin(frac * theta) / sin_theta)
    out = q0 * w0[:, None] + q1 * w1[:, None]  # (Q, 4)
    return out / np.linalg.norm(out, axis=1, keepdims=True)
