"""What a cnep MCAP file says about itself, read from its summary section alone (no chunk is decompressed).

    summary = read_summary(path, KIND_TRAJECTORY)  # episode, steps, duration, topics, extractor
    summary.n_steps, summary.width, summary.extractor

A few small reads at the end of the file (the footer, the summary section, the metadata records it indexes), so
checking thousands of files costs milliseconds each whatever their size; and whatever the file, what is read is
bounded: a summary section of at most MAX_SUMMARY_BYTES holding only the records a summary holds (no chunk, so
nothing is inflated), metadata records of at most MAX_METADATA_BYTES inside the data section. It trusts the file's
own index: a file whose data was damaged after writing reads here as it was written; the strict readers
(`read_trajectory`, `read_demonstration`) validate every CRC when the data itself is read.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Metadata, MetadataIndex

from cnep.recordings.chunks import CORRUPTION_ERRORS, RECORD_HEAD
from cnep.recordings.constants import (
    CHANNEL_KEY_VIEWS,
    CHANNEL_KEY_WIDTH,
    MAX_METADATA_BYTES,
    MAX_SUMMARY_BYTES,
    METADATA_EPISODE,
    METADATA_EXTRACTOR,
    METADATA_STEPS,
    TOPIC_IMAGE,
    TOPIC_TRAJECTORY,
    TOPIC_VIEWS,
)
from cnep.recordings.container import MCAP_MAGIC, McapContents, read_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.readers import in_file, read_episode
from cnep.recordings.records import Episode

_FOOTER = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC
_TAIL = RECORD_HEAD.size + _FOOTER.size + len(MCAP_MAGIC)  # the footer record and the closing magic
# What a summary section holds (the summary offsets after it included); a chunk or a message there is damage.
_SUMMARY_RECORDS = {
    Opcode.SCHEMA,
    Opcode.CHANNEL,
    Opcode.STATISTICS,
    Opcode.CHUNK_INDEX,
    Opcode.ATTACHMENT_INDEX,
    Opcode.METADATA_INDEX,
    Opcode.SUMMARY_OFFSET,
}
_READ = (METADATA_EPISODE, METADATA_STEPS, METADATA_EXTRACTOR)  # the metadata records a summary takes


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

    @property
    def views(self) -> int:
        """Views of the feature block a trajectory file holds per step (perception.views), 0 for none."""
        return int(self.topics.get(TOPIC_VIEWS, {}).get(CHANNEL_KEY_VIEWS, 0))


def read_summary(path: str | os.PathLike, kind: str) -> FileSummary:
    """The summary of the cnep MCAP file of `kind` at `path`, checked as the strict readers check a file's metadata
    (format version, kind, closed by its writer); RecordingError naming the file otherwise."""
    p = Path(path)
    try:
        with open(p, "rb") as stream:
            topics, metadata = _read_indexed(stream)
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror})") from None
    except CORRUPTION_ERRORS as exc:
        raise _why(p, f"no readable MCAP summary ({type(exc).__name__}: {exc})") from None
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
        topics=topics,
        extractor=metadata.get(METADATA_EXTRACTOR, {}),
    )


def _read_indexed(stream: IO[bytes]) -> tuple[dict[str, dict[str, str]], dict[str, dict[str, str]]]:
    """(topic -> its channel's metadata, name -> metadata record) of the open MCAP file `stream`, from its footer,
    summary section and the metadata records that indexes; ValueError where the file holds no such summary."""
    size = os.fstat(stream.fileno()).st_size
    if size < len(MCAP_MAGIC) + _TAIL:
        raise ValueError(f"{size} bytes, too short for an MCAP file with a footer")
    footer_at = size - _TAIL
    stream.seek(footer_at)
    tail = stream.read(_TAIL)
    opcode, length = RECORD_HEAD.unpack_from(tail)
    if opcode != Opcode.FOOTER or length != _FOOTER.size or tail[-len(MCAP_MAGIC) :] != MCAP_MAGIC:
        raise ValueError("no footer and closing magic at its end")
    start, _, crc = _FOOTER.unpack_from(tail, RECORD_HEAD.size)
    if start == 0:
        raise ValueError("no summary section")
    if not len(MCAP_MAGIC) <= start <= footer_at:
        raise ValueError(f"the footer's summary start {start} lies outside the file")
    if footer_at - start > MAX_SUMMARY_BYTES:
        raise ValueError(f"a summary section of {footer_at - start} bytes, more than the {MAX_SUMMARY_BYTES} read")
    stream.seek(start)
    section = stream.read(footer_at - start)
    if crc and zlib.crc32(tail[: RECORD_HEAD.size + 16], zlib.crc32(section)) != crc:
        raise ValueError("CRC mismatch in the summary section")
    topics, indexes = _summary_records(section)
    metadata = {index.name: _metadata_at(stream, index, start) for index in indexes}
    return topics, metadata


def _summary_records(section: bytes) -> tuple[dict[str, dict[str, str]], list[MetadataIndex]]:
    """The channels' metadata by topic and the index of each metadata record of _READ (its first) in the summary
    `section`, whose other records are skipped unparsed."""
    topics: dict[str, dict[str, str]] = {}
    indexes: dict[str, MetadataIndex] = {}
    pos = 0
    while pos < len(section):
        opcode, length = RECORD_HEAD.unpack_from(section, pos)
        body, end = pos + RECORD_HEAD.size, pos + RECORD_HEAD.size + length
        if opcode not in _SUMMARY_RECORDS or end > len(section):
            raise ValueError(f"a record of opcode {opcode} and {length} bytes at byte {pos} of the summary section")
        if opcode == Opcode.CHANNEL:
            channel = Channel.read(ReadDataStream(io.BytesIO(section[body:end])))
            topics.setdefault(channel.topic, dict(channel.metadata))
        elif opcode == Opcode.METADATA_INDEX:
            index = MetadataIndex.read(ReadDataStream(io.BytesIO(section[body:end])))
            if index.name in _READ:
                indexes.setdefault(index.name, index)
        pos = end
    return topics, list(indexes.values())


def _metadata_at(stream: IO[bytes], index: MetadataIndex, data_end: int) -> dict[str, str]:
    """The metadata record `index` points at, which must lie before `data_end` (the summary's start), be at most
    MAX_METADATA_BYTES and bear the index's name."""
    if index.length > MAX_METADATA_BYTES or index.length < RECORD_HEAD.size or index.offset + index.length > data_end:
        raise ValueError(f"the index of metadata {index.name!r} names {index.length} bytes at byte {index.offset}")
    stream.seek(index.offset)
    data = stream.read(index.length)
    opcode, length = RECORD_HEAD.unpack_from(data)
    if opcode != Opcode.METADATA or RECORD_HEAD.size + length != index.length:
        raise ValueError(f"the index of metadata {index.name!r} points at no metadata record (byte {index.offset})")
    record = Metadata.read(ReadDataStream(io.BytesIO(data[RECORD_HEAD.size :])))
    if record.name != index.name:
        raise ValueError(f"the index of metadata {index.name!r} points at the record {record.name!r}")
    return dict(record.metadata)


def _why(path: Path, problem: str) -> RecordingError:
    """The error of a file whose summary cannot be read: the strict reader's, which says whether it is truncated or
    corrupt and what to do (it reads the whole file, within its budget, but only for a file that is refused anyway)."""
    try:
        read_mcap(path)
    except RecordingError as exc:
        return exc
    return RecordingError(f"{path}: {problem}; rewrite it with `cnep repair {path} OUT`")
