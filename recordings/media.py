"""Frames from a video file or from numbered image files, as JPEG bytes (OpenCV, imported lazily).

JPEG images are kept byte for byte; other images and video frames are encoded as JPEG at
`JPEG_QUALITY`. All frames of one demonstration are held in memory (~35 KB per 640x480 frame).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from cnep.recordings.constants import JPEG_QUALITY
from cnep.recordings.errors import RecordingError
from cnep.recordings.validation import JPEG_MAGIC

VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv"})
IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp"})
_NUMBER = re.compile(r"(\d+)")
_FFMPEG_PREFIX = re.compile(r"^\[[^\]]*@ 0x[0-9a-f]+\]\s*")  # `[mov,mp4,m4a,3gp,3g2,mj2 @ 0x5581...] `

log = logging.getLogger(__name__)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_said_16_bit: list[str] = []  # the first 16-bit image reduced in this process (the warning is said once)


@contextlib.contextmanager
def native_stderr() -> Iterator[list[str]]:
    """Collect what native code (FFmpeg inside OpenCV) writes to the process's stderr during the block, instead of
    letting it reach the terminal around cnep's one line; the lines are in the yielded list after the block."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            lines.extend(line for line in captured.read().decode(errors="replace").splitlines() if line.strip())


def _ffmpeg_says(lines: list[str]) -> str:
    """` (FFmpeg: <its last line>)`, or "" when it said nothing."""
    return f" (FFmpeg: {_FFMPEG_PREFIX.sub('', lines[-1]).strip()})" if lines else ""


def _encode_jpeg(image: object, where: str) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RecordingError(f"{where}: could not encode the frame as JPEG")
    return buf.tobytes()


def read_video(path: str | os.PathLike) -> tuple[list[bytes], float]:
    """All frames of a video as JPEG bytes, and the video's frame rate in Hz."""
    import cv2

    p = Path(path)
    with native_stderr() as said:
        cap = cv2.VideoCapture(str(p))
        try:
            opened = cap.isOpened()
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) if opened else 0.0
            stated = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) if opened else 0
            frames = []
            while opened:
                ok, image = cap.read()
                if not ok:
                    break
                frames.append(_encode_jpeg(image, f"{p} frame {len(frames)}"))
        finally:
            cap.release()
    if not opened:
        raise RecordingError(
            f"{p}: cannot open this video{_ffmpeg_says(said)}: it is damaged, cut short before its index was "
            f"written, or not a video; export it again from the camera's recording"
        )
    if not frames:
        raise RecordingError(
            f"{p}: the video has no frames that decode{_ffmpeg_says(said)}; export it again from the camera's recording"
        )
    if not fps > 0:
        raise RecordingError(f"{p}: the video does not state its frame rate; give it with --frame-rate HZ")
    if stated > len(frames):
        log.warning(
            "%s: the video says it has %d frames but only the first %d decode%s: it is cut short or damaged",
            p,
            stated,
            len(frames),
            _ffmpeg_says(said),
        )
    return frames, fps


def numbered_images(folder: str | os.PathLike) -> list[Path]:
    """Image files in `folder` with a number in their name, ordered by that (last) number.

    frame_2 comes before frame_10; images without a number (a plot, a thumbnail) are not frames.
    """
    keyed = []
    for f in Path(folder).iterdir():
        numbers = _NUMBER.findall(f.stem)
        if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES and numbers:
            keyed.append((int(numbers[-1]), f))
    keyed.sort()
    for (a, fa), (b, fb) in zip(keyed, keyed[1:]):
        if a == b:
            raise RecordingError(f"{fa} and {fb} carry the same frame number {a}")
    return [f for _, f in keyed]


def as_jpeg(data: bytes, where: str) -> bytes:
    """JPEG bytes of an encoded image (PNG, BMP, ...): JPEG data is kept byte for byte, others re-encoded."""
    if bytes(data[:2]) == JPEG_MAGIC:
        return bytes(data)
    import cv2

    image = cv2.imdecode(np.frombuffer(bytes(data), np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise RecordingError(f"{where}: OpenCV cannot decode this image")
    if _png_bit_depth(data) == 16 and not _said_16_bit:
        _said_16_bit.append(where)
        log.warning(
            "%s: a 16-bit PNG image, reduced to 8 bits per channel (frames are stored as JPEG, and the feature "
            "network reads 8 bits); every 16-bit image is, and this is said once",
            where,
        )
    return _encode_jpeg(image, where)


def _png_bit_depth(data: bytes) -> int | None:
    """The bit depth a PNG's header declares (its IHDR chunk), None for data that is not PNG."""
    head = bytes(data[:25])
    return head[24] if len(head) == 25 and head[:8] == PNG_MAGIC and head[12:16] == b"IHDR" else None


def read_images(paths: list[Path]) -> list[bytes]:
    """JPEG bytes of each image (JPEG files as they are, checked to decode; others re-encoded)."""
    frames = [as_jpeg(p.read_bytes(), str(p)) for p in paths]
    bad = first_undecodable(frames)
    if bad is not None:
        raise RecordingError(
            f"{paths[bad]}: not a decodable JPEG (damaged or cut short); replace or remove it and ingest again"
        )
    return frames


def encode_raw_image(image: object, where: str) -> bytes:
    """JPEG bytes of an HxWx3 BGR (or HxW grey) uint8 array."""
    return _encode_jpeg(image, where)


def first_undecodable(frames: list[bytes]) -> int | None:
    """Index of the first frame whose JPEG does not decode, or None; cheap (an 8x reduced greyscale decode)."""
    import cv2
    import numpy as np

    for i, frame in enumerate(frames):
        buffer = np.frombuffer(frame, np.uint8)
        if not buffer.size or cv2.imdecode(buffer, cv2.IMREAD_REDUCED_GRAYSCALE_8) is None:
            return i
    return None


def check_decodable(frames: list[bytes] | None, where: str) -> None:
    """Raise RecordingError naming the step of the first frame that is not a decodable JPEG (None: no frames)."""
    bad = first_undecodable(frames) if frames else None
    if bad is not None:
        raise RecordingError(
            f"{where}: frame {bad} ({len(frames[bad])} bytes) is not a decodable JPEG; replace or "
            f"remove it at the source and ingest again"
        )


def video_frames_at(path: Path, times_s: np.ndarray, tolerance_s: float) -> list[bytes]:
    """JPEG frames of the video at `path` whose time is within `tolerance_s` of each of `times_s` (T,), in s, ascending.

    Decoded with PyAV (imported lazily), starting at the keyframe before the first wanted time; a wanted
    time with no frame near it is an error.
    """
    try:
        import av
    except ImportError:
        raise RecordingError(f"{path}: decoding this video needs PyAV: pip install 'cnep-pipeline[lerobot]'") from None
    frames: list[bytes] = []
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            if times_s[0] > 0:  # the keyframe at or before the first wanted frame
                container.seek(int(max(times_s[0] - 1.0, 0.0) / stream.time_base), stream=stream, backward=True)
            for frame in container.decode(stream):
                if frame.time is None:  # no presentation time: cannot be matched to a timestamp
                    continue
                t = float(frame.time)
                if t < times_s[len(frames)] - tolerance_s:
                    continue
                if abs(t - times_s[len(frames)]) > tolerance_s:
                    break  # the wanted time fell between two frames
                frames.append(encode_raw_image(frame.to_ndarray(format="bgr24"), f"{path} at {t:.4f} s"))
                if len(frames) == len(times_s):
                    break
    except av.error.FFmpegError as exc:
        raise RecordingError(f"{path}: cannot decode the video ({exc})") from None
    if len(frames) < len(times_s):
        raise RecordingError(
            f"{path}: no video frame within {tolerance_s * 1e3:g} ms of {times_s[len(frames)]:.4f} s "
            f"(frame {len(frames)} of {len(times_s)}); the video and the Parquet timestamps disagree"
        )
    return frames
