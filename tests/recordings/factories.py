"""Tiny synthetic recordings for tests (seeded; nothing read from disk)."""

from __future__ import annotations

import cv2
import numpy as np

from cnep.recordings import Demonstration, Episode, Trajectory


def jpeg_frames(steps: int, size: int = 16, seed: int = 0) -> list[bytes]:
    """`steps` real JPEG frames of size x size pixels with seeded random content."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(steps):
        img = rng.integers(0, 256, size=(size, size, 3), dtype=np.uint8)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        frames.append(buf.tobytes())
    return frames


def _frame_header_at(jpeg: bytes) -> int:
    """Where a JPEG's start-of-frame marker (its size) begins."""
    from cnep.recordings.validation import SOF_MARKERS

    i = 2
    while jpeg[i + 1] not in SOF_MARKERS:
        i += 2 + int.from_bytes(jpeg[i + 2 : i + 4], "big")
    return i


def cut_after_header(jpeg: bytes) -> bytes:
    """`jpeg` cut after its frame header: it declares its size, and decodes to nothing."""
    at = _frame_header_at(jpeg)
    return jpeg[: at + 2 + int.from_bytes(jpeg[at + 2 : at + 4], "big")]


def declaring(jpeg: bytes, width: int, height: int) -> bytes:
    """`jpeg` with its frame header declaring `width` x `height` pixels (its data as it was)."""
    data, at = bytearray(jpeg), _frame_header_at(jpeg)
    data[at + 5 : at + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    return bytes(data)


def random_pose(steps: int, rng: np.random.Generator) -> np.ndarray:
    """(steps, 7) float64: xyz in m and unit quaternions xyzw."""
    quat = rng.normal(size=(steps, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return np.concatenate([rng.uniform(-1, 1, size=(steps, 3)), quat], axis=1)


def demonstration_factory(
    steps: int = 20, frames: bool = True, seed: int = 0, episode_id: str = "demo-0", frame_size: int = 16
) -> Demonstration:
    rng = np.random.default_rng(seed)
    return Demonstration(
        episode=Episode(episode_id=episode_id, fps=10.0, task="pick", source="synthetic", extra={"robot": "sim"}),
        timestamps_ns=1_700_000_000_000_000_000 + np.arange(steps, dtype=np.int64) * 100_000_000,
        pose=random_pose(steps, rng),
        gripper=rng.uniform(0, 100, size=steps),
        frames=jpeg_frames(steps, size=frame_size, seed=seed) if frames else None,
        attachments={"calibration.json": b'{"fx": 500}'},
    )


def trajectory_factory(steps: int = 20, features: bool = True, frames: bool = False, seed: int = 0) -> Trajectory:
    demo = demonstration_factory(steps, frames=frames, seed=seed)
    rng = np.random.default_rng(seed + 1)
    feats = rng.normal(size=(steps, 1280)).astype(np.float32) if features else None
    extractor = {"architecture": "mobilenet_v2", "weights": "random", "weights_sha256": "0" * 64} if features else None
    return Trajectory.from_demonstration(demo, feats, extractor)
