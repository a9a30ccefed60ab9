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


BOMB_PLACEMENTS = ("no summary", "summary at the chunk", "metadata index at the chunk")


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def _metadata(name: str, data: dict[str, str]) -> bytes:
    entries = b"".join(_string(k) + _string(v) for k, v in data.items())
    return _record(Opcode.METADATA, _string(name) + struct.pack("<I", len(entries)) + entries)


def bombed_cnep_file(kind: str, placement: str, declared: int) -> bytes:
    """A cnep file of `kind` (its episode and steps metadata records, no messages) holding a zstd chunk of `declared`
    zero bytes (a few KB per 64 MiB), placed where a reader of the file's summary meets it (BOMB_PLACEMENTS): with no
    summary (the footer names none: the mcap library reads every record instead), a summary that starts at the
    chunk, or a summary whose index of the episode record points at the chunk."""
    from cnep.recordings.constants import METADATA_EPISODE, METADATA_STEPS
    from cnep.recordings.records import Episode
    from cnep.recordings.writers import episode_metadata, steps_metadata

    header = _record(Opcode.HEADER, _string("") + _string("cnep"))
    bomb = chunk_record(declared, zstd_zeros(declared))
    episode = _metadata(METADATA_EPISODE, episode_metadata(Episode("bomb", 10.0), kind))
    steps = _metadata(METADATA_STEPS, steps_metadata([0, 100_000_000]))
    chunk_at = 8 + len(header)
    episode_at = chunk_at + len(bomb)
    steps_at = episode_at + len(episode)
    data = b"\x89MCAP0\r\n" + header + bomb + episode + steps + _record(Opcode.DATA_END, struct.pack("<I", 0))
    indexed = (chunk_at, len(bomb)) if placement == "metadata index at the chunk" else (episode_at, len(episode))
    summary = _record(Opcode.METADATA_INDEX, struct.pack("<QQ", *indexed) + _string(METADATA_EPISODE)) + _record(
        Opcode.METADATA_INDEX, struct.pack("<QQ", steps_at, len(steps)) + _string(METADATA_STEPS)
    )
    summary_start = {"no summary": 0, "summary at the chunk": chunk_at}.get(placement, len(data))
    if placement == "no summary":
        summary = b""
    footer = _record(Opcode.FOOTER, struct.pack("<QQI", summary_start, 0, 0))
    return data + summary + footer + b"\x89MCAP0\r\n"
