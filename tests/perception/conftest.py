"""Tiny synthetic scenes for the perception tests (no files outside the repo)."""

import cv2
import numpy as np
import pytest


def scene_frames(scene: int, n: int = 4, height: int = 60, width: int = 80, seed: int = 0) -> np.ndarray:
    """(n, height, width, 3) uint8 frames of one scene: a seeded layout of coloured shapes on a plain background.

    Frames differ by a shift of up to 2 pixels and Gaussian sensor noise (std 2 grey levels), as a still
    camera would see them; different `scene` values give different layouts.
    """
    layout = np.random.default_rng(1000 + scene)
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = layout.integers(60, 200, 3)
    for _ in range(4):
        colour = tuple(int(c) for c in layout.integers(0, 256, 3))
        x, y = int(layout.integers(0, width)), int(layout.integers(0, height))
        if layout.random() < 0.5:
            cv2.circle(image, (x, y), int(layout.integers(5, 18)), colour, -1)
        else:
            cv2.rectangle(image, (x, y), (x + int(layout.integers(6, 30)), y + int(layout.integers(6, 24))), colour, -1)
    jitter = np.random.default_rng(seed)
    frames = []
    for _ in range(n):
        dy, dx = (int(v) for v in jitter.integers(-2, 3, 2))
        shifted = np.roll(image, (dy, dx), axis=(0, 1)).astype(np.float32)
        frames.append(np.clip(shifted + jitter.normal(0.0, 2.0, image.shape), 0, 255).astype(np.uint8))
    return np.stack(frames)  # (n, height, width, 3)


@pytest.fixture(scope="session")
def two_scenes() -> tuple[np.ndarray, np.ndarray]:
    """Frames of two different scenes, 4 each, 60x80 pixels."""
    return scene_frames(0), scene_frames(1, seed=1)
