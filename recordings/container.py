"""Low-level MCAP file access: atomic output files, and a strict or salvaging reader of all records.

Reading loads the whole file and walks it record by record with CRC validation of every chunk and of
the data section, so a flipped byte anywhere in the data section is caught. Every failure of the
mcap library (McapError, CRCValidationError, struct.error, zstd errors, ...) becomes one
`RecordingError` naming the file and saying whether it is truncated (fix: `cnep repair`) or corrupt.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterator

import zstandard
from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import CompressionType, Writer

from recordings.constants import CHUNK_SIZE_BYTES, COMPRESSION_BY_KIND, DEFAULT_COMPRESSION, LIBRARY_NAME, METADATA_EPISODE
from recordings.errors import RecordingError

MCAP_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time

# Everything the mcap/protobuf/zstd stack raises on damaged bytes.
CORRUPTION_ERRORS: tuple[type[BaseException], ...] = (
    McapError,
    ValueError,  # includes CRCValidationError and UnicodeDecodeError
    struct.error,
    EOFError,
    KeyError,
    IndexError,
    zstandard.ZstdError,
    DecodeError,
    MemoryError,
)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[IO[bytes]]:
    """Open a temporary file next to `path`; rename it to `path` only if the block completes.

    On any exception the temporary file is removed and `path` is left as it was.
    """
    target = Path(path)
    if not target.parent.is_dir():
        raise RecordingError(f"{target}: output folder {target.parent} does not exist; create it first")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


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


def chunk_records(chunk: Chunk) -> list[Schema | Channel | Message]:
    """Schemas, channels and messages of a chunk, after checking its CRC.

    Same result as `mcap.stream_reader.breakup_chunk(chunk, validate_crc=True)`, but message headers
    are unpacked with one precompiled struct instead of five stream reads each: reading a
    trajectory is dominated by this loop (one message per step).
    """
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    if len(data) != size:
        raise ValueError(f"chunk holds {len(data)} bytes, its header says {size}")
    out: list[Schema | Channel | Message] = []
    pos = 0
    while pos < size:
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        body, pos = pos + _RECORD_HEAD.size, pos + _RECORD_HEAD.size + length
        if pos > size:
            raise ValueError("a record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, body)
            out.append(Message(channel_id, log_time, data[body + _MESSAGE_HEAD.size : pos], publish_time, sequence))
        elif opcode == Opcode.SCHEMA:
            out.append(Schema.read(ReadDataStream(io.BytesIO(data[body:pos]))))
        elif opcode == Opcode.CHANNEL:
            out.append(Channel.read(ReadDataStream(io.BytesIO(data[body:pos]))))
    return out


def _describe(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def read_mcap(path: str | os.PathLike, salvage: bool = False) -> McapContents:
    """Read every record of the MCAP file at `path`.

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
    out = McapContents(path=p, size=len(data))
    if not data:
        raise RecordingError(f"{p}: empty file (0 bytes); the recording was never written")
    if not data.startswith(MCAP_MAGIC):
        raise RecordingError(f"{p}: not an MCAP file (it does not start with the MCAP magic bytes)")
    stream = io.BytesIO(data)
    reader = StreamReader(stream, emit_chunks=True, validate_crcs=True)
    try:
        for record in reader.records:
            if isinstance(record, Chunk):
                try:
                    inner = chunk_records(record)
                except CORRUPTION_ERRORS as exc:
                    if not salvage or stream.tell() >= len(data):
                        raise  # strict, or a chunk cut short by truncation: handled below
                    out.chunks_lost += 1
                    out.problem = f"a damaged chunk ending at byte {stream.tell()} was skipped ({_describe(exc)})"
                    out.bytes_used = stream.tell()
                    continue
                out.chunks_read += 1
                for r in inner:
                    _keep(out, r)
            else:
                _keep(out, record)
            out.bytes_used = stream.tell()
        out.complete = out.chunks_lost == 0
    except CORRUPTION_ERRORS as exc:
        truncated = stream.tell() >= len(data)
        where = f"at byte {out.bytes_used} of {len(data)}"
        if truncated:
            why = (
                f"truncated: it ends inside a record {where} (the recorder did not finish the file); "
                f"`cnep repair {p} OUT` salvages its {out.chunks_read} complete chunk(s)"
            )
        else:
            why = f"corrupt: unreadable record after byte {out.bytes_used} ({_describe(exc)}); the file was damaged after writing"
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
    elif isinstance(record, (DataEnd, Footer)):
        pass  # CRC checked by the stream reader; summary records repeat what we already have


def rewrite_mcap(dst: str | os.PathLike, contents: McapContents) -> Path:
    """Write `contents` as a new, complete MCAP file at `dst` (atomically), messages in time order.

    Schemas and channels keep their names, encodings and metadata (ids are reassigned); attachments
    and metadata records are copied; messages are sorted by log time (stable, so same-time messages
    keep their file order).
    """
    target = Path(dst)
    kind = contents.metadata.get(METADATA_EPISODE, {}).get("kind", "")
    with atomic_output(target) as stream:
        writer = new_writer(stream, COMPRESSION_BY_KIND.get(kind, DEFAULT_COMPRESSION))
        for a in contents.attachments:
            writer.add_attachment(create_time=a.create_time, log_time=a.log_time, name=a.name, media_type=a.media_type, data=a.data)
        for name, data in contents.metadata.items():
            writer.add_metadata(name, data)
        schema_ids = {
            old: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data) for old, s in contents.schemas.items()
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
                    channel_id=channel_ids[m.channel_id], log_time=m.log_time, data=m.data, publish_time=m.publish_time, sequence=m.sequence
                )
        writer.finish()
    return target
