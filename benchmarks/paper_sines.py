"""Multimodal sine demonstrations written from the paper's description alone, a second generator beside
`models.synthetic` for checking that a result is not a property of one generator.

The paper's synthetic sets are one-dimensional sensorimotor trajectories over normalised time, one behaviour per mode,
whose modes "intersect at various points" and "come close" where an intermediate conditioning point is sampled, with
demonstrations of one mode varying a little among themselves. Here mode k of K is a sine whose frequency rises with k,
all starting from the same point (a start every mode shares) and crossing each other in between; each demonstration
scales, shifts and delays its mode's sine a little. Nothing here is taken from `models.synthetic`.
"""

from __future__ import annotations

import numpy as np

STEPS = 200  # time steps per demonstration, t = 0 .. 1
PER_MODE = 32  # demonstrations per mode
BASE_CYCLES = 0.75  # cycles over [0, 1] of mode 0; mode k runs (1 + k / 2) times as many
AMPLITUDE_JITTER = 0.05  # std of a demonstration's amplitude factor around 1
OFFSET_JITTER = 0.03  # std of a demonstration's vertical offset
DELAY_JITTER = 0.01  # std of a demonstration's time shift (in units of the whole duration)


def paper_sines(n_modes: int, seed: int, per_mode: int = PER_MODE, steps: int = STEPS) -> tuple[np.ndarray, np.ndarray]:
    """`per_mode` demonstrations of each of `n_modes` sine behaviours -> trajectories (N, steps, 1) float32 and mode
    labels (N,) int, modes alternating, drawn from `seed`."""
    rng = np.random.default_rng(seed)
    modes = np.arange(n_modes * per_mode) % n_modes  # (N,)
    t = np.linspace(0.0, 1.0, steps)  # (T,)
    cycles = BASE_CYCLES * (1 + modes / 2)  # (N,)
    amplitude = 1 + AMPLITUDE_JITTER * rng.standard_normal(len(modes))  # (N,)
    offset = OFFSET_JITTER * rng.standard_normal(len(modes))  # (N,)
    delay = DELAY_JITTER * rng.standard_normal(len(modes))  # (N,)
    y = amplitude[:, None] * np.sin(2 * np.pi * cycles[:, None] * (t[None] - delay[:, None])) + offset[:, None]
    return y[..., None].astype(np.float32), modes
