"""The paper's PID controller: make an executed trajectory pass through the conditioning points.

CNEP is probabilistic, so a generated trajectory passes near, not through, its conditioning points.
Written from the paper's description (section "PID Controller"), not from the authors' notebook
(which flips the sign of the error and uses differences of consecutive points as the "error"):

1. Reference. The generated trajectory `y` (T, dy) is bent through the conditioning points
   `(k_j, c_j)`: `ref_i = y_i + sum_j w_j(i) a_j`, where the correction weight
   `w_j(i) = max(0, 1 - |i - k_j| / decay_steps)` is 1 at the point and decays to 0 over
   `decay_steps` steps on either side, and the offsets `a_j` are solved so that `ref_{k_j} = c_j`
   exactly (a small linear system; the hat kernel makes it positive definite for distinct points).
   Farther than `decay_steps` from every point, `ref` is the generated trajectory.
2. Tracking. The executed point `x` follows the reference with feed-forward of its step plus a PID on
   the error `e_i = ref_i - x_i` (reference minus current point: a positive error pushes `x` up):
   `u_i = kp e_i + ki sum_{j<=i} e_j dt + kd (e_i - e_{i-1}) / dt`,
   `x_{i+1} = x_i + (ref_{i+1} - ref_i) + u_i dt`.
   Started on the reference, `x` is the reference (passes through every point); started elsewhere
   (the robot's actual position), the error decays to 0 and `x` converges to the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnep.models.errors import ConfigError


@dataclass(frozen=True)
class PIDGains:
    """Gains per step (`dt` in steps), and how many steps the correction takes to decay to 0."""

    kp: float = 0.6  # defaults: settle a unit offset to < 1e-4 within ~40 steps (tests/models/test_pid.py)
    ki: float = 0.1
    kd: float = 0.3
    decay_steps: int = 20
    dt: float = 1.0

    def __post_init__(self) -> None:
        if min(self.kp, self.ki, self.kd) < 0:
            raise ConfigError(f"PID gains must be >= 0, got kp={self.kp}, ki={self.ki}, kd={self.kd}.")
        if self.decay_steps < 1 or not self.dt > 0:
            raise ConfigError(f"PID decay_steps must be >= 1 and dt > 0, got {self.decay_steps} and {self.dt}.")


def correction_weights(T: int, indices: np.ndarray, decay_steps: int) -> np.ndarray:
    """(T, n) hat weights: 1 at each conditioning index, 0 from `decay_steps` steps away."""
    steps = np.arange(T)[:, None]  # (T, 1)
    return np.clip(1.0 - np.abs(steps - indices[None, :]) / decay_steps, 0.0, None)  # (T, n)


def reference(generated: np.ndarray, indices: np.ndarray, values: np.ndarray, decay_steps: int) -> np.ndarray:
    """The generated trajectory (T, dy) bent to pass exactly through `values` (n, dy) at `indices` (n,)."""
    y, k, c = _check(generated, indices, values)
    W = correction_weights(len(y), k, decay_steps)  # (T, n)
    offsets = np.linalg.solve(W[k], c - y[k])  # (n, dy): W[k] is (n, n) with ones on the diagonal
    return y + W @ offsets  # (T, dy)


def pid_track(
    generated: np.ndarray,
    indices: np.ndarray,
    values: np.ndarray,
    gains: PIDGains = PIDGains(),
    start: np.ndarray | None = None,
) -> np.ndarray:
    """The executed trajectory (T, dy) from the PID tracking the corrected reference.

    generated (T, dy) or (T,); indices (n,) step indices of the conditioning points; values (n, dy);
    start (dy,) the executed trajectory's first point (default: on the reference).
    """
    ref = reference(generated, indices, values, gains.decay_steps)  # (T, dy)
    x = np.empty_like(ref)
    x[0] = ref[0] if start is None else np.asarray(start, dtype=np.float64).reshape(ref.shape[1])
    integral = np.zeros(ref.shape[1])
    e_prev = ref[0] - x[0]
    for i in range(len(ref) - 1):
        e = ref[i] - x[i]  # (dy,) reference minus current point
        integral += e * gains.dt
        u = gains.kp * e + gains.ki * integral + gains.kd * (e - e_prev) / gains.dt
        x[i + 1] = x[i] + (ref[i + 1] - ref[i]) + u * gains.dt
        e_prev = e
    return x.reshape(np.shape(generated)) if np.ndim(generated) == 1 else x


def _check(generated, indices, values) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    y = np.asarray(generated, dtype=np.float64)
    y = y[:, None] if y.ndim == 1 else y  # (T, dy)
    if y.ndim != 2 or len(y) < 2:
        raise ConfigError(f"The generated trajectory must be (T, dy) with T >= 2, got shape {np.shape(generated)}.")
    k = np.asarray(indices, dtype=np.int64).reshape(-1)  # (n,)
    c = np.asarray(values, dtype=np.float64).reshape(len(k), y.shape[1])  # (n, dy)
    if len(k) and (k.min() < 0 or k.max() >= len(y) or len(np.unique(k)) != len(k)):
        raise ConfigError(f"Conditioning indices must be distinct steps in [0, {len(y)}), got {k.tolist()}.")
    return y, k, c
