"""`cnep inspect`: what an MCAP file holds and whether it is complete (any MCAP, not only ours).

Damage does not stop the report: a truncated or corrupt file is read as far as `cnep repair` would
salvage, and the report says what is wrong. For cnep files the strict reader is also run, and every
frame is decoded (a cheap reduced decode), so the report says whether the pipeline will accept the file.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from cnep.recordings.constants import (
    CHANNEL_KEY_BLOCKS,
    KIND_DEMONSTRATION,
    KIND_TRAJECTORY,
    METADATA_EPISODE,
    TOPIC_IMAGE,
)
from cnep.recordings.container import read_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.media import first_undecodable
from cnep.recordings.readers import demonstration_from, trajectory_from
from cnep.runtime.jsonfile import parse_json

NS_PER_S = 1e9


@dataclass(frozen=True)
class TopicSummary:
    topic: str
    schema: str
    count: int
    start_ns: int
    end_ns: int

    @property
    def rate_hz(self) -> float:
        """Mean message rate over the topic's own time span (0 for fewer than 2 messages)."""
        span = self.end_ns - self.start_ns
        return (self.count - 1) * NS_PER_S / span if self.count > 1 and span > 0 else 0.0


@dataclass(frozen=True)
class FileReport:
    path: Path
    size: int
    complete: bool
    problem: str | None
    library: str
    topics: list[TopicSummary]
    metadata: dict[str, dict[str, str]]
    attachments: list[tuple[str, str, int]]  # name, media type, bytes
    chunks: int
    blocks: dict[str, object] = field(default_factory=dict)  # topic -> column blocks from channel metadata
    check: str | None = None  # cnep files: "ok" or why the pipeline refuses the file

    @property
    def duration_s(self) -> float:
        if not self.topics:
            return 0.0
        return (max(t.end_ns for t in self.topics) - min(t.start_ns for t in self.topics)) / NS_PER_S


def inspect_file(path: str | os.PathLike) -> FileReport:
    """Report on one file; RecordingError only if it is missing, empty or not MCAP at all."""
    contents = read_mcap(path, salvage=True)
    topics = []
    for ch in sorted(contents.channels.values(), key=lambda c: c.topic):
        times = [m.log_time for m in contents.messages if m.channel_id == ch.id]
        topics.append(
            TopicSummary(
                ch.topic, contents.schema_name(ch.topic), len(times), min(times, default=0), max(times, default=0)
            )
        )
    blocks = {}
    for ch in contents.channels.values():
        if CHANNEL_KEY_BLOCKS in ch.metadata:
            try:
                blocks[ch.topic] = parse_json(ch.metadata[CHANNEL_KEY_BLOCKS])
            except ValueError:
                blocks[ch.topic] = ch.metadata[CHANNEL_KEY_BLOCKS]
    check = None
    kind = contents.metadata.get(METADATA_EPISODE, {}).get("kind")
    if kind in (KIND_DEMONSTRATION, KIND_TRAJECTORY):
        if not contents.complete:
            check = f"refused: {contents.problem}"
        else:
            try:
                record = (demonstration_from if kind == KIND_DEMONSTRATION else trajectory_from)(contents)
                bad = first_undecodable(record.frames) if record.frames else None
                check = (
                    "ok"
                    if bad is None
                    else (
                        f"refused: {contents.path}: frame {bad} on {TOPIC_IMAGE} is not a decodable JPEG; "
                        f"ingest the recording again from its source"
                    )
                )
            except RecordingError as exc:
                check = f"refused: {exc}"
    return FileReport(
        path=contents.path,
        size=contents.size,
        complete=contents.complete,
        problem=contents.problem,
        library=contents.header.library if contents.header else "",
        topics=topics,
        metadata=contents.metadata,
        attachments=[(a.name, a.media_type, len(a.data)) for a in contents.attachments],
        chunks=contents.chunks_read,
        blocks=blocks,
        check=check,
    )


def format_report(report: FileReport) -> str:
    """Human-readable multi-line report."""
    state = "yes" if report.complete else f"NO: {report.problem}"
    lines = [
        f"{report.path}",
        f"  size {report.size} bytes, {report.chunks} chunk(s), written by {report.library or 'unknown'}",
        f"  complete: {state}",
    ]
    if report.check is not None:
        lines.append(f"  cnep check: {report.check}")
    lines.append(f"  duration {report.duration_s:.3f} s")
    lines.append("  topics:")
    wt = max((len(t.topic) for t in report.topics), default=0)
    ws = max((len(t.schema) for t in report.topics), default=0)
    for t in report.topics:
        lines.append(f"    {t.topic:<{wt}}  {t.schema:<{ws}}  {t.count:>7} msgs  {t.rate_hz:8.2f} Hz")
    for name, data in report.metadata.items():
        lines.append(f"  metadata {name}: " + ", ".join(f"{k}={v}" for k, v in data.items()))
    for topic, blocks in report.blocks.items():
        lines.append(f"  column blocks of {topic}: {json.dumps(blocks)}")
    for name, media, size in report.attachments:
        lines.append(f"  attachment {name} ({media}, {size} bytes)")
    return "\n".join(lines)
