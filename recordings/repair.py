"""Salvage the complete chunks and messages of a truncated or damaged MCAP file into a new, valid file.

A recorder killed before closing leaves a file without summary and footer, often ending inside a
chunk. Every chunk read in full with a valid CRC is kept; a damaged chunk in the middle is skipped;
of the chunk the end of the file cuts, every complete message in the part that decodes is kept (lz4
frames and zstd streams decode a prefix, block by block); reading stops at the first unreadable
record. For cnep files the steps are trimmed to those present on every per-step topic (a step cut in
half is dropped), the `steps` record is rewritten and a `repair` record says where the data came
from. The input is never modified.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from cnep.recordings.constants import (
    KIND_DEMONSTRATION,
    KIND_TRAJECTORY,
    METADATA_EPISODE,
    METADATA_REPAIR,
    METADATA_STEPS,
    TOPIC_GRIPPER,
    TOPIC_IMAGE,
    TOPIC_POSE,
    TOPIC_TRAJECTORY,
    TOPIC_VIEWS,
)
from cnep.recordings.container import McapContents, read_mcap, refuse_overwrite_input, rewrite_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.readers import demonstration_from, trajectory_from
from cnep.recordings.writers import steps_metadata

STEP_TOPICS = {KIND_DEMONSTRATION: (TOPIC_POSE, TOPIC_GRIPPER), KIND_TRAJECTORY: (TOPIC_TRAJECTORY,)}


@dataclass(frozen=True)
class RepairReport:
    """What `repair` kept: messages per topic, chunks kept/skipped, bytes used of the input."""

    src: Path
    dst: Path
    size: int
    bytes_used: int
    chunks_read: int
    chunks_lost: int
    partial_messages: int  # messages kept from the chunk the end of the file cuts
    partial_lost_messages: int  # about how many messages the lost part of that chunk held
    messages: dict[str, int]
    steps: int | None  # cnep files: complete steps kept; None for other MCAP files
    was_complete: bool
    problem: str | None

    def summary(self) -> str:
        """One line for the CLI."""
        msgs = ", ".join(f"{t} {n}" for t, n in sorted(self.messages.items()))
        steps = f"{self.steps} complete steps; " if self.steps is not None else ""
        problem = (self.problem or "").split("; `cnep repair")[0]  # the advice to repair is done here
        state = "the input was already complete" if self.was_complete else f"lost: {problem}"
        cut = (
            f" and {self.partial_messages} message(s) of the chunk the end of the file cuts (about "
            f"{self.partial_lost_messages} more of it lost)"
            if self.partial_messages
            else ""
        )
        return (
            f"wrote {self.dst}: {steps}{sum(self.messages.values())} messages ({msgs}) kept "
            f"from {self.chunks_read} complete chunk(s){cut}, "
            f"{self.bytes_used} of {self.size} bytes of {self.src} read in whole records, "
            f"{self.chunks_lost} damaged chunk(s) skipped; {state}"
        )


def _trim_steps(contents: McapContents, kind: str) -> list[int]:
    """Keep only steps present on every per-step topic; returns the kept step times (ns)."""
    optional = (TOPIC_IMAGE, TOPIC_VIEWS)  # per-step topics a file may hold
    topics = [t for t in (*STEP_TOPICS[kind], *optional) if contents.channel_of_topic(t) is not None]
    if len(topics) < len(STEP_TOPICS[kind]) or not topics:
        missing = [t for t in STEP_TOPICS[kind] if contents.channel_of_topic(t) is None]
        raise RecordingError(
            f"{contents.path}: no complete chunk holds topic(s) {missing}; nothing of the {kind} can be salvaged"
        )
    ids = {contents.channel_of_topic(t).id for t in topics}  # type: ignore[union-attr]
    per_topic = [{m.log_time for m in contents.topic_messages(t)} for t in topics]
    common = set.intersection(*per_topic)
    contents.messages = [m for m in contents.messages if m.channel_id not in ids or m.log_time in common]
    return sorted(common)


def repair(src: str | os.PathLike, dst: str | os.PathLike) -> RepairReport:
    """Write the salvageable part of `src` to `dst` (atomically) and report what was kept."""
    refuse_overwrite_input(src, dst)
    contents = read_mcap(src, salvage=True)
    contents.messages = [m for m in contents.messages if m.channel_id in contents.channels]  # channel lost with a chunk
    if not contents.messages:
        raise RecordingError(
            f"{contents.path}: nothing to salvage: no complete chunk with messages ({contents.problem})"
        )
    kind = contents.metadata.get(METADATA_EPISODE, {}).get("kind")
    steps = None
    if kind in STEP_TOPICS:
        times = _trim_steps(contents, kind)
        if not times:
            raise RecordingError(f"{contents.path}: nothing to salvage: no step is complete on all its topics")
        contents.metadata[METADATA_STEPS] = steps_metadata(times)
        steps = len(times)
    contents.metadata[METADATA_REPAIR] = {
        "source": str(contents.path),
        "source_bytes": str(contents.size),
        "bytes_used": str(contents.bytes_used),
        "chunks_read": str(contents.chunks_read),
        "chunks_lost": str(contents.chunks_lost),
        "partial_messages": str(contents.partial_messages),
        "problem": contents.problem or "",
    }
    out = rewrite_mcap(dst, contents)
    if kind in STEP_TOPICS:  # the salvaged file must read back like any other
        try:
            (demonstration_from if kind == KIND_DEMONSTRATION else trajectory_from)(read_mcap(out))
        except RecordingError:
            out.unlink()
            raise
    messages: dict[str, int] = {}
    for m in contents.messages:
        topic = contents.channels[m.channel_id].topic
        messages[topic] = messages.get(topic, 0) + 1
    return RepairReport(
        src=contents.path,
        dst=out,
        size=contents.size,
        bytes_used=contents.bytes_used,
        chunks_read=contents.chunks_read,
        chunks_lost=contents.chunks_lost,
        partial_messages=contents.partial_messages,
        partial_lost_messages=contents.partial_lost_messages,
        messages=messages,
        steps=steps,
        was_complete=contents.complete,
        problem=contents.problem,
    )
