"""Frame decoding and resizing with OpenCV: bytes or any-size uint8 RGB frames -> (N, 224, 224, 3) uint8."""

from __future__ import annotations

import numpy as np

from cnep.perception.constants import IMAGE_SIZE
from cnep.perception.errors import PerceptionError
from cnep.runtime.frames import decode_frame, resize_frame


def decode_image(data: bytes) -> np.ndarray:
    """Decode one compressed image (JPEG, PNG, ...) into an (H, W, 3) uint8 RGB array.

    Raises PerceptionError when the bytes are not a decodable image; the caller names the file and step.
    """
    frame = decode_frame(data)
    if frame is None:
        raise PerceptionError(f"cannot decode image ({len(data)} bytes): not a valid JPEG/PNG")
    return frame  # (H, W, 3)


def check_frames(frames: np.ndarray) -> None:
    """Raise PerceptionError unless `frames` is an (N, H, W, 3) uint8 array with N, H, W >= 1."""
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8:
        kind = frames.dtype if isinstance(frames, np.ndarray) else type(frames).__name__
        raise PerceptionError(
            f"frames must be a uint8 numpy array of RGB pixels, got {kind}; convert with "
            f"np.asarray(frames, dtype=np.uint8)"
        )
    if frames.ndim != 4 or frames.shape[-1] != 3 or 0 in frames.shape[1:3]:
        raise PerceptionError(
            f"frames must have shape (N, H, W, 3), got {frames.shape}; stack single frames with frames[None]"
        )


def resize_frames(frames: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """Resize (N, H, W, 3) uint8 frames of any size to (N, size, size, 3) uint8 (full frame, no crop).

    INTER_AREA averages the source pixels under each target pixel, which avoids aliasing when shrinking; the
    runtime resizes a robot's frames with the same function (runtime.frames.resize_frame).
    """
    check_frames(frames)
    if frames.shape[1:3] == (size, size):
        return np.ascontiguousarray(frames)
    out = np.empty((len(frames), size, size, 3), dtype=np.uint8)  # (N, size, size, 3)
    for i, frame in enumerate(frames):
        resize_frame(frame, out[i])
    return out
