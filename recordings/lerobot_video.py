"""A camera's frames as one MP4 file of a LeRobot dataset, encoded with PyAV at the frames' own times.

Each frame is presented at the time it is given (s from the file's start, kept to the microsecond: the
stream's time base is 1 us), so a recording at an irregular rate keeps its steps' times and a reader finds
every frame at `from_timestamp + timestamp` (LeRobot's rule). The encoder's settings are LeRobot's defaults
(`VideoSettings`): AV1 by SVT-AV1 at CRF 30, a keyframe every 2 frames, yuv420p.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from cnep.recordings.errors import RecordingError
from cnep.recordings.lerobot_layout import INSTALL_HINT

CODECS = ("libsvtav1", "h264", "hevc")  # the encoders LeRobot's own recorder offers (its `vcodec` names)
PIXEL_FORMATS = ("yuv420p", "yuv444p")
TIME_BASE = Fraction(1, 1_000_000)  # s per unit of a frame's presentation time


@dataclass(frozen=True)
class VideoSettings:
    """How frames are encoded; the defaults are LeRobot's own recorder's."""

    codec: str = field(default=CODECS[0], metadata={"help": "the video encoder (libsvtav1: AV1)", "choices": CODECS})
    crf: int = field(
        default=30, metadata={"help": "constant rate factor: lower keeps more detail (0 with h264: lossless in YUV)"}
    )
    pix_fmt: str = field(
        default=PIXEL_FORMATS[0],
        metadata={
            "help": "pixel format: yuv420p halves the colour resolution, yuv444p keeps it",
            "choices": PIXEL_FORMATS,
        },
    )
    keyframe_every: int = field(
        default=2, metadata={"help": "frames from one keyframe to the next (a frame decodes from the last keyframe)"}
    )

    def __post_init__(self) -> None:
        if self.codec not in CODECS or self.pix_fmt not in PIXEL_FORMATS:
            raise RecordingError(
                f"video codec {self.codec!r} / pixel format {self.pix_fmt!r}: choose a codec of {', '.join(CODECS)} "
                f"and a pixel format of {', '.join(PIXEL_FORMATS)}"
            )
        if self.crf < 0 or self.keyframe_every < 1:
            raise RecordingError(f"video crf {self.crf} must be >= 0, keyframe_every {self.keyframe_every} >= 1")

    def options(self) -> dict[str, str]:
        """The encoder's options (FFmpeg's names): keyframe interval, CRF, and SVT-AV1's fastest preset."""
        options = {"g": str(self.keyframe_every), "crf": str(self.crf)}
        return options | ({"preset": "12"} if self.codec == "libsvtav1" else {})


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise RecordingError(f"writing LeRobot videos needs PyAV: {INSTALL_HINT}") from None
    return av


@contextlib.contextmanager
def _encoder_log_quiet() -> Iterator[None]:
    """SVT-AV1 prints its warnings to the process's stderr when its encoder opens; errors only while it does (its
    SVT_LOG level), unless the user set a level."""
    if "SVT_LOG" in os.environ:
        yield
        return
    os.environ["SVT_LOG"] = "1"
    try:
        yield
    finally:
        os.environ.pop("SVT_LOG", None)


class _Sink:
    """The file object the muxer writes through: `file` until it is set to None, then nowhere. An aborted muxer still
    writes its trailer and seeks, and on a full disk each of those fails again; PyAV prints every failure it has no
    caller to raise to, after the command's error line."""

    def __init__(self, file: io.BufferedWriter) -> None:
        self.file: io.BufferedWriter | None = file

    def write(self, data: bytes) -> int:
        return len(data) if self.file is None else self.file.write(data)

    def seek(self, offset: int, whence: int = 0) -> int:
        return 0 if self.file is None else self.file.seek(offset, whence)

    def tell(self) -> int:
        return 0 if self.file is None else self.file.tell()


class VideoFile:
    """One MP4 being written: frames added at their times (`add`), closed when complete (`close`)."""

    def __init__(self, path: Path, width: int, height: int, fps: float, settings: VideoSettings) -> None:
        av = _av()
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(path, "wb")  # noqa: SIM115 - held by the muxer until close() or abort()
        self._sink = _Sink(self._file)
        self._container = av.open(self._sink, "w", format="mp4")
        self._stream = None
        try:
            rate = Fraction(fps).limit_denominator(1001)
            stream = self._container.add_stream(settings.codec, rate=rate, options=settings.options())
            stream.width, stream.height, stream.pix_fmt = width, height, settings.pix_fmt
            stream.codec_context.time_base = TIME_BASE
            with _encoder_log_quiet():
                stream.codec_context.open()
        except (av.error.FFmpegError, ValueError) as exc:
            self.abort()
            raise RecordingError(
                f"{path}: the {settings.codec} encoder refuses {width}x{height} frames in {settings.pix_fmt} ({exc}); "
                f"choose another codec or pixel format (h264 in yuv420p needs an even width and height)"
            ) from None
        self._stream = stream
        self._last_pts = -1
        self._bytes = 0  # of the encoded frames so far

    def add(self, rgb: np.ndarray, time_s: float) -> None:
        """Encode one frame (H, W, 3) uint8 RGB, presented `time_s` s after the file's start (later than the last)."""
        av = _av()
        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
        frame.pts = round(time_s / TIME_BASE)
        frame.time_base = TIME_BASE
        if frame.pts <= self._last_pts:
            raise RecordingError(f"{self.path}: a frame at {time_s:.6f} s is not after the previous one")
        self._last_pts = frame.pts
        packets = self._stream.encode(frame)
        self._bytes += sum(packet.size for packet in packets)
        self._container.mux(packets)

    def close(self) -> None:
        """Flush the encoder and finish the file."""
        self._container.mux(self._stream.encode())
        self._container.close()
        self._file.close()

    def abort(self) -> None:
        """Close whatever fails (the file is incomplete and will be removed; a full disk frees the space it held only
        once it is closed). The encoder is told the stream ended (SVT-AV1 prints an error when it is not), and what
        it still held is dropped."""
        self._sink.file = None  # what the muxer still writes goes nowhere: the file is incomplete whatever it holds
        with contextlib.suppress(Exception):
            if self._stream is not None:
                self._stream.encode()
        with contextlib.suppress(Exception):
            self._container.close()
        with contextlib.suppress(OSError):
            self._file.close()

    @property
    def size_mb(self) -> float:
        """The size of the frames encoded so far, MB (the encoder may hold the last few back)."""
        return self._bytes / 2**20

    @property
    def canonical_codec(self) -> str:
        """The codec's own name (`av1`, `h264`, `hevc`), as LeRobot's info.json states it."""
        return self._stream.codec_context.codec.canonical_name
