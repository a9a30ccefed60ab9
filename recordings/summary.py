"""What a cnep MCAP file says about itself, read from its summary section alone (no chunk is decompressed).

    summary = read_summary(path, KIND_TRAJECTORY)  # episode, steps, duration, topics, extractor
    summary.n_steps, summary.width, summary.extractor

A few small reads at the end of the file (the footer, the summary, the metadata records it indexes), so
checking thousands of files costs milliseconds each whatever their size. It trusts the file's own index:
a file whose data was damaged after writing reads here as it was written; the strict readers
(`read_trajectory`, `read_demonstration`) validate every CRC when the data itself is read.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader

from cnep.recordings.constants import (
    CHANNEL_KEY_WIDTH,
    METADATA_EXTRACTOR,
    METADATA_STEPS,
    TOPIC_IMAGE,
    TOPIC_TRAJECTORY,
)
from cnep.recordings.container import CORRUPTION_ERRORS, McapContents, read_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.readers import in_file, read_episode
from cnep.recordings.records import Episode


@dataclass(frozen=True)
class FileSummary:
    """A cnep file's metadata: its episode, steps, first-to-last step time (ns), each topic's channel metadata, and
    the feature extractor's identity ({} for none)."""

    path: Path
    episode: Episode
    n_steps: int
    duration_ns: int
    topics: dict[str, dict[str, str]] = field(default_factory=dict)
    extractor: dict[str, str] = field(default_factory=dict)

    @property
    def has_frames(self) -> bool:
        """Whether the file carries camera frames."""
        return TOPIC_IMAGE in self.topics

    @property
    def width(self) -> int:
        """Columns of a trajectory file's per-step vector (0 for a file without one)."""
        return int(self.topics.get(TOPIC_TRAJECTORY, {}).get(CHANNEL_KEY_WIDTH, 0))


def read_summary(path: str | os.PathLike, kind: str) -> FileSummary:
    """The summary of the cnep MCAP file of `kind` at `path`, checked as the strict readers check a file's metadata
    (format version, kind, closed by its writer); RecordingError naming the file otherwise."""
    p = Path(path)
    try:
        with open(p, "rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror})") from None
    except CORRUPTION_ERRORS + (json.JSONDecodeError,) as exc:
        raise _why(p, f"no readable MCAP summary ({type(exc).__name__}: {exc})") from None
    if summary is None:
        raise _why(p, "no summary section")
    episode = read_episode(McapContents(path=p, size=0, metadata=metadata), kind)
    with in_file(p):
        steps = metadata[METADATA_STEPS]
        try:
            n_steps, duration_ns = int(steps["n_steps"]), int(steps["duration_ns"])
        except (KeyError, ValueError) as exc:
            raise RecordingError(f"its '{METADATA_STEPS}' record lacks a valid {exc}") from None
    return FileSummary(
        path=p,
        episode=episode,
        n_steps=n_steps,
        duration_ns=duration_ns,
        topics={channel.topic: dict(channel.metadata) for channel in summary.channels.values()},
        extractor=metadata.get(METADATA_EXTRACTOR, {}),
    )


def _why(path: Path, problem: str) -> RecordingError:
    """The error of a file whose summary cannot be read: the strict reader's, which says whether it is truncated or
    corrupt and what to do (it reads the whole file, but only for a file that is refused anyway)."""
    try:
        read_mcap(path)
    except RecordingError as exc:
        return exc
    return RecordingError(f"{path}: {problem}; rewrite it with `cnep repair {path} OUT`")
