"""Hostile MCAP files built byte by byte: chunks whose declared sizes lie, and decompression bombs."""

from __future__ import annotations

import io
import struct
import zlib

import zstandard
from mcap.opcode import Opcode
from mcap.writer import Writer

_CHUNK_HEAD = struct.Struct("<QQQII")  # start time, end time, uncompressed size, uncompressed CRC, compression length


def zstd_zeros(size: int) -> bytes:
    """A zstd frame of `size` zero bytes that does not state its own size (streamed): a few KB per 64 MiB."""
    compressor = zstandard.ZstdCompressor(level=3).compressobj()
    piece = b"\0" * min(size, 16 << 20)
    parts = [compressor.compress(piece[: min(len(piece), size - done)]) for done in range(0, size, len(piece))]
    return b"".join([*parts, compressor.flush()])


def chunk_record(declared: int, data: bytes, compression: str = "zstd", crc: int = 0) -> bytes:
    """An MCAP chunk record (opcode and length included) that declares `declared` uncompressed bytes."""
    name = compression.encode()
    body = _CHUNK_HEAD.pack(0, 0, declared, crc, len(name)) + name + struct.pack("<Q", len(data)) + data
    return struct.pack("<BQ", Opcode.CHUNK, len(body)) + body


def mcap_with(records: list[bytes]) -> bytes:
    """A complete MCAP file (header, `records`, data end, footer, magic) without a summary or CRCs to contradict."""
    stream = io.BytesIO()
    writer = Writer(
        stream,
        use_chunking=False,
        use_statistics=False,
        use_summary_offsets=False,
        repeat_channels=False,
        repeat_schemas=False,
        enable_crcs=False,
    )
    writer.start(profile="", library="hostile")
    writer.finish()
    empty = stream.getvalue()
    header_end = 8 + 9 + struct.unpack_from("<Q", empty, 9)[0]  # magic, opcode + length, header body
    return empty[:header_end] + b"".join(records) + empty[header_end:]


def zero_chunk(declared: int) -> bytes:
    """A chunk of `declared` zero bytes that declares its size and CRC truthfully."""
    return chunk_record(declared, zstd_zeros(declared), crc=zlib.crc32(b"\0" * declared))
