"""A hostile MCAP file costs bounded memory and time: declared sizes are range-checked and decompression stops
one byte past them, within the file's budget; each case is one line and exit 2."""

from functools import cache

import lz4.frame
import pytest

from cnep.pipeline.cli.main import main
from cnep.recordings import RecordingError, read_demonstration
from cnep.recordings.chunks import decoded
from cnep.recordings.constants import INFLATION_GRACE_BYTES, MAX_CHUNK_BYTES
from cnep.recordings.inspection import inspect_file
from tests.recordings.hostile import chunk_record, mcap_with, zero_chunk, zstd_zeros


@cache
def bomb() -> bytes:
    return zstd_zeros(2 << 30)  # 2 GiB of zeros in about 70 KB


# name -> (the chunk record, what the one line says)
CASES = {
    "declares 2 GiB": (lambda: chunk_record(2 << 30, bomb()), "declares 2147483648 bytes uncompressed, more than"),
    "declares 1 KiB, inflates to 2 GiB": (lambda: chunk_record(1024, bomb()), "inflates to more than the 1024 bytes"),
    "declares 2^64-1": (
        lambda: chunk_record(2**64 - 1, bomb()),
        "declares 18446744073709551615 bytes uncompressed, more than the 67108864 a chunk may hold",
    ),
    "lz4 past its size": (lambda: chunk_record(10, lz4.frame.compress(bytes(4096)), "lz4"), "inflates to more than"),
    "short of its size": (lambda: chunk_record(4096, zstd_zeros(100)), "inflates to 100 bytes, not the 4096 bytes"),
    "unknown compression": (lambda: chunk_record(3, b"abc", "bz2"), "unknown chunk compression 'bz2'"),
    "zero records": (lambda: zero_chunk(1024), "a record of the reserved opcode 0"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_lying_chunk_is_damage_in_one_line_exit_2_for_inspect_repair_and_the_readers(tmp_path, capsys, case):
    record, says = CASES[case]
    path = tmp_path / "hostile.mcap"
    path.write_bytes(mcap_with([record()]))
    with pytest.raises(RecordingError, match=f"{path}: corrupt: damaged chunk at byte .*{says}"):
        read_demonstration(path)
    assert says in inspect_file(path).problem
    for argv in (["inspect", str(path)], ["repair", str(path), str(tmp_path / "out.mcap")]):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and says in err[0], err
    assert not (tmp_path / "out.mcap").exists()


def test_chunks_within_the_limit_but_past_the_files_budget_are_damage_at_once(tmp_path):
    path = tmp_path / "many.mcap"
    path.write_bytes(mcap_with([zero_chunk(INFLATION_GRACE_BYTES // 2)] * 40))  # 40 MiB of zeros from a few KB
    problem = inspect_file(path).problem
    assert (
        "40 damaged chunk(s) skipped" in problem and "left of its file's budget (100 times the file's size)" in problem
    )


def test_decoding_stops_at_the_bytes_asked_for_whatever_the_frame_holds():
    assert len(decoded("zstd", bomb(), 1000)) == 1000
    assert len(decoded("lz4", lz4.frame.compress(b"\0" * 100_000), 10)) == 10
    assert MAX_CHUNK_BYTES < 2 << 30
