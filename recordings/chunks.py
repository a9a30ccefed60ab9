"""An MCAP chunk's records, decompressed within a bound: a hostile chunk costs bounded memory and time.

A chunk declares its uncompressed size; it is decompressed here as a stream that stops one byte past that size,
never trusting the compressed frame's own idea of its size (the mcap library's reader allocates whatever a zstd
frame claims). A chunk that declares more than MAX_CHUNK_BYTES, or more than its file's budget has left
(recordings.constants), or that inflates past what it declares, is damaged: ValueError, which the reader reports as
one line naming the file.
"""

from __future__ import annotations

import io
import struct
import zlib

import zstandard
from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema

from cnep.recordings.constants import MAX_CHUNK_BYTES, MAX_INFLATION

RECORD_HEAD = struct.Struct("<BQ")  # opcode, body length
MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
# Everything the mcap/protobuf/zstd stack raises on damaged bytes.
CORRUPTION_ERRORS: tuple[type[BaseException], ...] = (
    McapError,
    ValueError,  # includes CRCValidationError and UnicodeDecodeError
    struct.error,
    EOFError,
    KeyError,
    IndexError,
    OverflowError,
    zstandard.ZstdError,
    DecodeError,
    MemoryError,
)
RESERVED_OPCODE = 0  # never a record: a run of zero bytes read as records would cost a loop turn per 9 bytes


def decoded(compression: str, data: bytes | memoryview, at_most: int) -> bytes:
    """At most `at_most` bytes of the uncompressed form of a chunk's `data` (`compression` "zstd", "lz4" or ""); of
    data cut short, as much as its complete blocks give. ValueError for an unknown compression."""
    if compression == "":
        return bytes(data[:at_most])
    if compression == "zstd":
        return zstandard.ZstdDecompressor().stream_reader(data).read(at_most)
    if compression == "lz4":
        import lz4.frame  # a dependency of mcap

        try:
            return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=at_most)
        except RuntimeError as exc:  # lz4 says "LZ4F_decompress failed" of damaged data with this type alone
            raise ValueError(f"lz4: {exc}") from None
    raise ValueError(f"unknown chunk compression {compression[:40]!r}")


def inflate(compression: str, data: bytes | memoryview, declared: int, crc: int, limit: int) -> bytes:
    """The `declared` uncompressed bytes of a chunk's `data`, checked against their CRC (0: none); ValueError if
    `declared` exceeds MAX_CHUNK_BYTES or `limit` (what is left of the file's budget, bytes), the data inflates to
    more or fewer bytes, or the CRC differs."""
    if declared > MAX_CHUNK_BYTES:
        raise ValueError(
            f"the chunk declares {declared} bytes uncompressed, more than the {MAX_CHUNK_BYTES} a chunk may hold"
        )
    if declared > limit:
        raise ValueError(
            f"the chunk declares {declared} bytes uncompressed, more than the {limit} left of its file's budget "
            f"({MAX_INFLATION} times the file's size): a decompression bomb, or damage"
        )
    out = decoded(compression, data, declared + 1)
    if len(out) != declared:
        more = "more than" if len(out) > declared else f"{len(out)} bytes, not"
        raise ValueError(f"the chunk inflates to {more} the {declared} bytes it declares")
    if crc and zlib.crc32(out) != crc:
        raise ValueError(f"the chunk's uncompressed CRC {zlib.crc32(out):08x} differs from the {crc:08x} it declares")
    return out


def chunk_records(data: bytes, partial: bool = False) -> tuple[list[Schema | Channel | Message], int]:
    """The schemas, channels and messages in uncompressed chunk `data`, and the bytes they span.

    partial=False: a record that runs past the end or does not parse raises (ValueError, struct.error, ...).
    partial=True (`data` is a prefix of a chunk cut short): reading stops before the first such record.
    Message headers are unpacked with one precompiled struct instead of five stream reads each: reading a
    trajectory is dominated by this loop (one message per step).
    """
    out: list[Schema | Channel | Message] = []
    pos, size = 0, len(data)
    while pos + (RECORD_HEAD.size if partial else 1) <= size:
        opcode, length = RECORD_HEAD.unpack_from(data, pos)
        body, end = pos + RECORD_HEAD.size, pos + RECORD_HEAD.size + length
        try:
            if end > size:
                raise ValueError("a record runs past the end of its chunk")
            if opcode == RESERVED_OPCODE:
                raise ValueError(f"a record of the reserved opcode 0 at byte {pos} of the chunk")
            if opcode == Opcode.MESSAGE:
                channel_id, sequence, log_time, publish_time = MESSAGE_HEAD.unpack_from(data, body)
                out.append(Message(channel_id, log_time, data[body + MESSAGE_HEAD.size : end], publish_time, sequence))
            elif opcode == Opcode.SCHEMA:
                out.append(Schema.read(ReadDataStream(io.BytesIO(data[body:end]))))
            elif opcode == Opcode.CHANNEL:
                out.append(Channel.read(ReadDataStream(io.BytesIO(data[body:end]))))
        except CORRUPTION_ERRORS:
            if partial:
                break
            raise
        pos = end
    return out, pos
