"""Views of a demonstration: its frames as a camera a little moved, under other light, with other sensor noise.

A few dozen demonstrations show a model a few dozen scenes; from their features alone an encoder can tell them apart
by what a robot's next scene will not repeat (where exactly the camera sat, how bright the room was). A view redraws
those: one draw per view and demonstration, kept for all its frames as a camera is (a shift of the whole image, a
gain and an offset of its brightness), and pixel noise drawn per frame. `cnep extract --views N` writes each
demonstration's features under N views beside its own (`recordings.Trajectory.views`), and `cnep train` trains on
every view of its training demonstrations, validating on their own features (docs/concepts.md).

Draws are seeded by the extraction's seed and the demonstration's episode id: the same file gives the same views.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import cv2
import numpy as np

from cnep.perception.constants import MAX_VIEWS
from cnep.perception.errors import PerceptionError

SHIFT_PX = 4.0  # the image shifted by up to this many pixels (of the network's 224) along each axis
GAIN = 0.15  # brightness multiplied by 1 +- up to this
OFFSET = 12.0  # then moved by up to this many levels (of 255)
PIXEL_NOISE = 3.0  # std of the per-pixel noise, in levels


@dataclass(frozen=True)
class View:
    """One view's draw: the shift (dx, dy) in pixels, the gain and offset of the brightness, the noise's seed."""

    dx: float
    dy: float
    gain: float
    offset: float
    noise_seed: int

    def apply(self, pixels: np.ndarray, first_step: int) -> np.ndarray:
        """(B, H, W, 3) uint8 frames, the demonstration's steps first_step.. -> the same frames under this view."""
        h, w = pixels.shape[1:3]
        shift = np.float32([[1, 0, self.dx], [0, 1, self.dy]])
        out = np.empty_like(pixels)
        for i, frame in enumerate(pixels):
            moved = cv2.warpAffine(frame, shift, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            noise = np.random.default_rng([self.noise_seed, first_step + i]).normal(0.0, PIXEL_NOISE, moved.shape)
            out[i] = np.clip(moved.astype(np.float32) * self.gain + self.offset + noise, 0, 255).round()
        return out


@dataclass(frozen=True)
class Views:
    """How many views of each demonstration to extract (0: none) and the seed of their draws."""

    count: int
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, int) or not 0 <= self.count <= MAX_VIEWS:
            raise PerceptionError(f"--views must be a whole number from 0 to {MAX_VIEWS}, got {self.count!r}")

    def of(self, episode_id: str) -> list[View]:
        """The views of the demonstration `episode_id`."""
        rng = np.random.default_rng([self.seed, zlib.crc32(episode_id.encode("utf-8"))])
        views = []
        for _ in range(self.count):
            dx, dy = rng.uniform(-SHIFT_PX, SHIFT_PX, 2)
            gain, offset = 1.0 + rng.uniform(-GAIN, GAIN), rng.uniform(-OFFSET, OFFSET)
            views.append(View(float(dx), float(dy), float(gain), float(offset), int(rng.integers(2**32))))
        return views
