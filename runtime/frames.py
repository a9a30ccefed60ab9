"""A camera frame -> the feature network's input: uint8 RGB (H, W, 3) resized to IMAGE_SIZE x IMAGE_SIZE.

Compressed frames (the recordings' JPEG) are decoded by OpenCV to RGB first (`decode_frame`).

INTER_AREA averages the source pixels under each target pixel (no aliasing when shrinking); the full frame
is kept, no crop. The perception package resizes with the same function, so the features a policy computes
are the ones it was trained on.
"""

from __future__ import annotations

import cv2
import numpy as np

from cnep.runtime.constants import IMAGE_SIZE


def decode_frame(data: bytes) -> np.ndarray | None:
    """One compressed image (JPEG, PNG, ...) as an (H, W, 3) uint8 RGB array; None if the bytes do not decode."""
    buffer = np.frombuffer(data, dtype=np.uint8)
    bgr = cv2.imdecode(buffer, cv2.IMREAD_COLOR) if buffer.size else None
    return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)  # (H, W, 3)


def resize_frame(frame: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Resize one uint8 RGB frame (H, W, 3) into `out` (size, size, 3) uint8, in place; returns `out`."""
    if frame.shape[:2] == out.shape[:2]:
        out[...] = frame
    else:
        cv2.resize(frame, out.shape[1::-1], dst=out, interpolation=cv2.INTER_AREA)
    return out


def pixel_buffer(n: int = 1) -> np.ndarray:
    """A preallocated (n, IMAGE_SIZE, IMAGE_SIZE, 3) uint8 input of the feature network."""
    return np.empty((n, IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
