"""What cnep reads of its own bookkeeping in an output folder is read within a size limit: a planted record or lock
file of any size costs bounded memory."""

import json
import os
import tracemalloc

import pytest

from cnep.outputs import RECORD_FILE, OutputError, output_lock, read_record
from cnep.outputs.lock import lock_path
from cnep.outputs.record import MAX_RECORD_BYTES, RECORD_VERSION


def peak_of(read) -> tuple[object, int]:
    """What `read()` returns and the most bytes Python held while it ran."""
    tracemalloc.start()
    try:
        return read(), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_record_larger_than_the_limit_is_no_record_and_is_not_read_whole(tmp_path):
    entries = {f"f{k}.mcap": {"size": 1, "sha256": "0" * 64} for k in range(3)}
    text = json.dumps({"format_version": RECORD_VERSION, "files": entries})
    with open(tmp_path / RECORD_FILE, "w") as f:
        f.write(text[:-2] + ', "pad": "')  # a valid start, then a string run out to four times the limit
        f.truncate(4 * MAX_RECORD_BYTES)  # sparse: costs no disk
    found, peak = peak_of(lambda: read_record(tmp_path))
    assert found is None and peak < 1.5 * MAX_RECORD_BYTES, peak


def test_a_record_within_the_limit_is_read(tmp_path):
    entries = {"a.mcap": {"size": 1, "sha256": "0" * 64}}
    (tmp_path / RECORD_FILE).write_text(json.dumps({"format_version": RECORD_VERSION, "files": entries}))
    assert read_record(tmp_path) == entries


def test_a_record_that_is_no_regular_file_is_no_record_and_is_not_waited_for(tmp_path):
    os.mkfifo(tmp_path / RECORD_FILE)  # opening a pipe for reading waits for a writer that never comes
    assert read_record(tmp_path) is None


def test_a_planted_lock_file_of_any_size_costs_bounded_memory(tmp_path):
    path = lock_path(tmp_path / "out.mcap", folder=False)
    with open(path, "w") as f:
        f.write('{"pid": 1, "host": "elsewhere", "command": "')  # a lock file's start, then 64 MB of one string
        f.truncate(64 << 20)

    def lock_and_release() -> None:
        with output_lock(tmp_path / "out.mcap"):
            pass

    _, peak = peak_of(lock_and_release)
    assert peak < 1 << 20, peak
    assert not path.exists()  # taken over and released


def test_a_pipe_where_the_lock_goes_is_refused_and_not_waited_for(tmp_path):
    os.mkfifo(lock_path(tmp_path / "out.mcap", folder=False))
    with (
        pytest.raises(OutputError, match="this is where the output's lock file goes, and it is no file"),
        output_lock(tmp_path / "out.mcap"),
    ):
        pass
