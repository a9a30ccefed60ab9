"""Low-level MCAP file access: a strict or salvaging reader of all records, and the writer set-up.

Reading loads the whole file and walks it record by record, validating the CRC of every chunk, of
the data section, of attachments and of the summary, so a flipped byte anywhere is caught. Every
failure (McapError, CRCValidationError, struct.error, zstd errors, ...) becomes one `RecordingError`
naming the file and saying whether it is truncated (fix: `cnep repair`) or corrupt.
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
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from cnep.outputs import atomic_file
from cnep.recordings.chunks import CORRUPTION_ERRORS, RECORD_HEAD, chunk_records, decoded, inflate
from cnep.recordings.constants import (
    CHUNK_SIZE_BYTES,
    COMPRESSION_BY_KIND,
    DEFAULT_COMPRESSION,
    INFLATION_GRACE_BYTES,
    LIBRARY_NAME,
    MAX_CHUNK_BYTES,
    MAX_INFLATION,
    METADATA_EPISODE,
)
from cnep.recordings.errors import RecordingError

MCAP_MAGIC = b"\x89MCAP0\r\n"
_CHUNK_HEAD = struct.Struct("<QQQII")  # start time, end time, uncompressed size, uncompressed CRC, compression length
_U64 = struct.Struct("<Q")


def mcap_library(path: str | os.PathLike) -> str | None:
    """The `library` of the MCAP file's header (who wrote it), or None if `path` is no MCAP file with a header.

    Reads the first record only, so a file cut short after its header still tells who wrote it.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(64 * 1024)
    except OSError:
        return None
    if not head.startswith(MCAP_MAGIC) or len(head) < len(MCAP_MAGIC) + RECORD_HEAD.size:
        return None
    opcode, length = RECORD_HEAD.unpack_from(head, len(MCAP_MAGIC))
    body = len(MCAP_MAGIC) + RECORD_HEAD.size
    if opcode != Opcode.HEADER or body + length > len(head):
        return None
    try:
        return Header.read(ReadDataStream(io.BytesIO(head[body : body + length]))).library
    except CORRUPTION_ERRORS:
        return None


def refuse_overwrite_input(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Raise if `dst` is the same file as `src` (nothing ever overwrites its input)."""
    if Path(dst).exists() and Path(src).exists() and os.path.samefile(src, dst):
        raise RecordingError(f"{dst}: output is the input file; choose another output path")


_COMPRESSION_TYPES = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}


def new_writer(stream: IO[bytes], compression: str = DEFAULT_COMPRESSION) -> Writer:
    """An mcap Writer with `compression` chunks ("zstd", "lz4", ""), chunk and data-section CRCs, started."""
    writer = Writer(
        stream,
        chunk_size=CHUNK_SIZE_BYTES,
        compression=_COMPRESSION_TYPES[compression],
        enable_crcs=True,
        enable_data_crcs=True,
    )
    writer.start(profile="", library=LIBRARY_NAME)
    return writer


@dataclass
class McapContents:
    """All records of an MCAP file, in file order.

    complete: the footer and closing magic were reached with every CRC valid.
    problem: why reading stopped early (salvage mode), else None.
    chunks_read / chunks_lost: complete valid chunks kept / damaged chunks skipped (salvage mode).
    partial_messages / partial_lost_bytes / partial_lost_messages: messages recovered from a chunk cut short by
    the end of the file, how many of its uncompressed bytes could not be, and about how many messages those
    held (at the recovered ones' mean size) (salvage mode; a prefix of lz4 and zstd data decodes).
    """

    path: Path
    size: int
    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    complete: bool = False
    problem: str | None = None
    chunks_read: int = 0
    chunks_lost: int = 0
    bytes_used: int = 0  # offset just after the last record read in full
    inflated: int = 0  # uncompressed bytes of the chunks decompressed so far
    partial_messages: int = 0
    partial_lost_bytes: int = 0
    partial_lost_messages: int = 0

    def chunk_limit(self) -> int:
        """The most bytes the next chunk may inflate to: MAX_CHUNK_BYTES, and what is left of the file's budget of
        INFLATION_GRACE_BYTES + MAX_INFLATION times its size for all its chunks together."""
        return max(0, min(MAX_CHUNK_BYTES, INFLATION_GRACE_BYTES + MAX_INFLATION * self.size - self.inflated))

    def channel_of_topic(self, topic: str) -> Channel | None:
        for ch in self.channels.values():
            if ch.topic == topic:
                return ch
        return None

    def require_channel(self, topic: str, hint: str = "") -> Channel:
        """The channel of `topic`; RecordingError naming the file and its topics if it is absent."""
        ch = self.channel_of_topic(topic)
        if ch is None:
            have = sorted({c.topic for c in self.channels.values()}) or "none"
            raise RecordingError(f"{self.path}: missing topic {topic!r} (topics in the file: {have}){hint}")
        return ch

    def topic_messages(self, topic: str) -> list[Message]:
        """Messages on `topic` in file order; RecordingError naming the file if the topic is absent."""
        ch = self.require_channel(topic)
        return [m for m in self.messages if m.channel_id == ch.id]

    def schema_name(self, topic: str) -> str:
        ch = self.channel_of_topic(topic)
        schema = self.schemas.get(ch.schema_id) if ch is not None else None
        return schema.name if schema is not None else ""


def _describe(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class _Damage(Exception):
    """Reading stopped at damage; `truncated` tells a cut-off file from one damaged after writing."""

    def __init__(self, text: str, truncated: bool):
        super().__init__(text)
        self.truncated = truncated


# Records parsed from the top level of the file. Index, statistics and summary-offset records only
# repeat what the data section holds, so they are skipped unparsed (a message index costs two reads
# per message in the mcap library, a large part of reading a trajectory).
_TOP_LEVEL = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.METADATA: Metadata.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.DATA_END: DataEnd.read,
    Opcode.FOOTER: Footer.read,
}


def _chunk_at(view: memoryview, body: int, end: int) -> Chunk:
    """The chunk record whose body spans view[body:end], its compressed data a view (no copy)."""
    start, stop, usize, ucrc, clen = _CHUNK_HEAD.unpack_from(view, body)
    compression = str(view[body + _CHUNK_HEAD.size : body + _CHUNK_HEAD.size + clen], "utf-8")
    data_at = body + _CHUNK_HEAD.size + clen + _U64.size
    (dlen,) = _U64.unpack_from(view, data_at - _U64.size)
    if data_at + dlen > end:
        raise ValueError("chunk data runs past the end of its record")
    return Chunk(compression, view[data_at : data_at + dlen], stop, start, ucrc, usize)  # type: ignore[arg-type]


def _salvage_cut_chunk(view: memoryview, body: int, out: McapContents) -> None:
    """Keep the complete records at the start of a chunk that the end of the file cuts: its compressed data is
    decoded as far as it goes (no CRC covers a part of a chunk: each record is kept only if it parses in full)."""
    size = len(view)
    if body + _CHUNK_HEAD.size > size:
        return
    _, _, usize, _, clen = _CHUNK_HEAD.unpack_from(view, body)
    data_at = body + _CHUNK_HEAD.size + clen + _U64.size
    if data_at > size:
        return
    compression = str(view[body + _CHUNK_HEAD.size : body + _CHUNK_HEAD.size + clen], "utf-8", errors="replace")
    at_most = min(usize, out.chunk_limit())
    out.inflated += at_most
    try:
        kept, pos = chunk_records(decoded(compression, view[data_at:size], at_most), partial=True)
    except CORRUPTION_ERRORS:  # whatever the decoder says about damaged data, nothing is recovered
        return
    for record in kept:
        _keep(out, record)
    out.partial_messages = sum(isinstance(r, Message) for r in kept)
    out.partial_lost_bytes = max(0, usize - pos)
    out.partial_lost_messages = round(out.partial_lost_bytes * out.partial_messages / pos) if pos else 0


def _walk(data: bytes, out: McapContents, salvage: bool) -> None:
    """Read the records of `data` into `out`, checking every CRC; raise _Damage where reading stops."""
    size, pos, view = len(data), len(MCAP_MAGIC), memoryview(data)
    # A file cut short does not end with the closing magic; one damaged in place still does.
    closed = size >= 2 * len(MCAP_MAGIC) and data.endswith(MCAP_MAGIC)
    while True:
        if pos + RECORD_HEAD.size > size:
            raise _Damage(f"it ends inside a record at byte {pos} of {size}", truncated=True)
        opcode, length = RECORD_HEAD.unpack_from(data, pos)
        body, end = pos + RECORD_HEAD.size, pos + RECORD_HEAD.size + length
        if end > size:
            if salvage and opcode == Opcode.CHUNK:
                _salvage_cut_chunk(view, body, out)
            raise _Damage(
                f"the record at byte {pos} runs past the end of the file ({size} bytes)", truncated=not closed
            )
        if opcode in (Opcode.MESSAGE, Opcode.CHUNK) or opcode in _TOP_LEVEL:
            record = _record_at(data, view, opcode, pos, body, end)
            if isinstance(record, Chunk):
                _take_chunk(record, pos, out, salvage)
            elif isinstance(record, DataEnd):
                _check_data_end(record, view, pos, out, salvage)
            elif isinstance(record, Attachment):
                _check_attachment(record, data, view, body, end)
                _keep(out, record)
            elif isinstance(record, Footer):
                out.bytes_used = end
                _check_footer(record, data, view, body, end)
                return
            else:
                _keep(out, record)
        pos = out.bytes_used = end


def _record_at(data: bytes, view: memoryview, opcode: int, pos: int, body: int, end: int) -> object:
    """The record of `opcode` whose body is data[body:end]; _Damage if it cannot be read."""
    try:
        if opcode == Opcode.CHUNK:
            return _chunk_at(view, body, end)
        stream = ReadDataStream(io.BytesIO(data[body:end]))
        return Message.read(stream, end - body) if opcode == Opcode.MESSAGE else _TOP_LEVEL[opcode](stream)
    except CORRUPTION_ERRORS as exc:
        raise _Damage(f"unreadable record at byte {pos} ({_describe(exc)})", truncated=False) from None


def _take_chunk(chunk: Chunk, pos: int, out: McapContents, salvage: bool) -> None:
    """The chunk's records into `out`, inflated within its limits; a damaged one is _Damage, or skipped and counted
    when salvaging."""
    try:
        limit = out.chunk_limit()
        out.inflated += chunk.uncompressed_size if chunk.uncompressed_size <= limit else 0
        args = chunk.compression, chunk.data, chunk.uncompressed_size, chunk.uncompressed_crc, limit
        inner, _ = chunk_records(inflate(*args))
    except CORRUPTION_ERRORS as exc:
        if not salvage:
            raise _Damage(f"damaged chunk at byte {pos} ({_describe(exc)})", truncated=False) from None
        out.chunks_lost += 1
        out.problem = f"{out.chunks_lost} damaged chunk(s) skipped, the last at byte {pos} ({_describe(exc)})"
        return
    out.chunks_read += 1
    for record in inner:
        _keep(out, record)


def _check_data_end(record: DataEnd, view: memoryview, pos: int, out: McapContents, salvage: bool) -> None:
    """The data section's CRC: a mismatch is _Damage, or noted in `out` when salvaging."""
    if record.data_section_crc and zlib.crc32(view[:pos]) != record.data_section_crc:
        if not salvage:
            raise _Damage("CRC mismatch in the data section (a byte outside the chunks changed)", truncated=False)
        out.problem = out.problem or "CRC mismatch in the data section"


def _check_attachment(record: Attachment, data: bytes, view: memoryview, body: int, end: int) -> None:
    """The attachment's CRC (its record's last 4 bytes); _Damage on a mismatch."""
    stored = struct.unpack_from("<I", data, end - 4)[0]
    if stored and zlib.crc32(view[body : end - 4]) != stored:
        raise _Damage(f"CRC mismatch in attachment {record.name!r} at byte {body - RECORD_HEAD.size}", truncated=False)


def _check_footer(record: Footer, data: bytes, view: memoryview, body: int, end: int) -> None:
    """The closing magic after the footer and the summary section's CRC; _Damage otherwise."""
    if data[end:] != MCAP_MAGIC:
        raise _Damage("no closing magic bytes after the footer", truncated=len(data) < end + len(MCAP_MAGIC))
    if (
        record.summary_crc
        and record.summary_start
        and zlib.crc32(view[record.summary_start : body + 16]) != record.summary_crc
    ):
        raise _Damage("CRC mismatch in the summary section", truncated=False)


def read_mcap(path: str | os.PathLike, salvage: bool = False) -> McapContents:
    """Read every record of the MCAP file at `path`, validating chunk, data-section, attachment and
    summary CRCs.

    salvage=False: any damage raises RecordingError naming the file and the fix.
    salvage=True: keep every record before the damage, skip chunks that fail their CRC, stop at
    the first unreadable record, and describe the damage in `problem` (never raises for damage).
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{p}: is a folder, not an MCAP file") from None
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror})") from None
    if not data:
        raise RecordingError(f"{p}: empty file (0 bytes); the recording was never written")
    if not data.startswith(MCAP_MAGIC):
        raise RecordingError(f"{p}: not an MCAP file (it does not start with the MCAP magic bytes)")
    out = McapContents(path=p, size=len(data))
    try:
        _walk(data, out, salvage)
        out.complete = out.chunks_lost == 0 and out.problem is None
    except _Damage as damage:
        if damage.truncated and not salvage and not out.messages:  # would a message by message salvage find any?
            out = read_mcap(p, salvage=True)
            out.messages = []
        if damage.truncated and not out.messages and not out.partial_messages:
            why = (
                f"truncated: {damage} (the recorder did not finish the file) and no chunk holds a complete "
                f"message, so nothing can be salvaged; record or export it again"
            )
        elif damage.truncated:
            cut = (
                f" and the {out.partial_messages} complete message(s) of the chunk the end cuts (about "
                f"{out.partial_lost_messages} more of it are lost)"
                if out.partial_messages
                else ""
            )
            why = (
                f"truncated: {damage} (the recorder did not finish the file); "
                f"`cnep repair {p} OUT` salvages its {out.chunks_read} complete chunk(s){cut}"
            )
        else:
            why = f"corrupt: {damage}; the file was damaged after writing"
        if not salvage:
            raise RecordingError(f"{p}: {why}") from None
        out.problem = why
    return out


def _keep(out: McapContents, record: object) -> None:
    if isinstance(record, Header):
        out.header = record
    elif isinstance(record, Schema):
        out.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        out.channels.setdefault(record.id, record)
    elif isinstance(record, Message):
        out.messages.append(record)
    elif isinstance(record, Metadata):
        out.metadata[record.name] = dict(record.metadata)
    elif isinstance(record, Attachment):
        out.attachments.append(record)


def rewrite_mcap(dst: str | os.PathLike, contents: McapContents) -> Path:
    """Write `contents` as a new, complete MCAP file at `dst` (atomically), messages in time order.

    Schemas and channels keep their names, encodings and metadata (ids are reassigned); attachments
    and metadata records are copied; messages are sorted by log time (stable, so same-time messages
    keep their file order).
    """
    target = Path(dst)
    kind = contents.metadata.get(METADATA_EPISODE, {}).get("kind", "")
    with atomic_file(target) as stream:
        writer = new_writer(stream, COMPRESSION_BY_KIND.get(kind, DEFAULT_COMPRESSION))
        for a in contents.attachments:
            writer.add_attachment(
                create_time=a.create_time, log_time=a.log_time, name=a.name, media_type=a.media_type, data=a.data
            )
        for name, data in contents.metadata.items():
            writer.add_metadata(name, data)
        schema_ids = {
            old: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data)
            for old, s in contents.schemas.items()
        }
        channel_ids = {
            old: writer.register_channel(
                topic=c.topic,
                message_encoding=c.message_encoding,
                schema_id=schema_ids.get(c.schema_id, 0),
                metadata=dict(c.metadata),
            )
            for old, c in contents.channels.items()
        }
        for m in sorted(contents.messages, key=lambda m: m.log_time):
            if m.channel_id in channel_ids:
                writer.add_message(
                    channel_id=channel_ids[m.channel_id],
                    log_time=m.log_time,
                    data=m.data,
                    publish_time=m.publish_time,
                    sequence=m.sequence,
                )
        writer.finish()
    return target
