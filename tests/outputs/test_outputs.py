"""cnep.outputs: files renamed into place only when complete, one run per output, leftovers of dead runs removed."""

from __future__ import annotations

import errno
import json
import logging
import os
import stat
import subprocess
import sys

import pytest

from cnep.outputs import (
    FOLDER_LOCK,
    OutputError,
    atomic_file,
    lock_path,
    output_lock,
    remove_stale_temporaries,
    staged,
    temporary_path,
    write_atomically,
)


def dead_pid() -> int:
    """The id of a process that has ended (and been reaped)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def test_a_file_appears_only_when_complete_with_the_users_umask(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic_file(tmp_path / "a.bin") as stream:
            stream.write(b"data")
            assert not (tmp_path / "a.bin").exists()
            assert len(list(tmp_path.iterdir())) == 1 and temporary_path(tmp_path / "a.bin").parent == tmp_path
    finally:
        os.umask(old)
    assert (tmp_path / "a.bin").read_bytes() == b"data" and [p.name for p in tmp_path.iterdir()] == ["a.bin"]
    assert stat.S_IMODE((tmp_path / "a.bin").stat().st_mode) == 0o640


@pytest.mark.parametrize("error", [KeyboardInterrupt, ValueError])
def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, error):
    write_atomically(tmp_path / "a.bin", b"old")
    with pytest.raises(error), atomic_file(tmp_path / "a.bin") as stream:
        stream.write(b"half")
        raise error
    assert (tmp_path / "a.bin").read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_a_full_disk_names_the_file(tmp_path):
    with pytest.raises(OSError) as raised, atomic_file(tmp_path / "a.bin"):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # what write() says: no file name
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == str(tmp_path / "a.bin")
    assert list(tmp_path.iterdir()) == []


def test_staged_files_appear_together_or_not_at_all(tmp_path):
    write_atomically(tmp_path / "b.json", b"old")
    with pytest.raises(KeyboardInterrupt), staged() as staging:
        staging.write(tmp_path / "a.rrd", b"rrd")
        staging.write(tmp_path / "b.json", b"new")
        raise KeyboardInterrupt  # interrupted before the end: nothing changes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.json"] and (tmp_path / "b.json").read_bytes() == b"old"
    with staged() as staging:
        part = staging.write(tmp_path / "part", b"p", keep=False)  # an intermediate, for a writer that merges
        with staging.open(tmp_path / "a.rrd") as stream:
            stream.write(part.read_bytes() + b"rrd")
        staging.write(tmp_path / "b.json", b"new")
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["b.json"]
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == {"a.rrd": b"prrd", "b.json": b"new"}


def test_only_temporaries_of_dead_processes_are_removed(tmp_path, caplog):
    dead = tmp_path / f".a.mcap.{dead_pid()}-abcdef.tmp"
    live = tmp_path / f".a.mcap.{os.getpid()}-abcdef.tmp"
    other = tmp_path / f".b.mcap.{dead_pid()}-abcdef.tmp"
    user = tmp_path / ".notes.tmp"  # not one of ours
    nested = tmp_path / f".{dead.name}.{dead.name.split('.')[-2]}.tmp"  # a writer's own temporary of one
    for path in (dead, live, other, user, nested):
        path.write_bytes(b"x")
    with caplog.at_level(logging.WARNING):
        assert remove_stale_temporaries(tmp_path, ["a.mcap"]) == 2
    assert "removed 2 temporary file(s) left by an interrupted run" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in (live, other, user))
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / dead.name).write_bytes(b"x")
    assert remove_stale_temporaries(tmp_path, recursive=True) == 2  # `other`, and the one in sub/
    assert sorted(p.name for p in tmp_path.rglob("*.tmp")) == sorted([live.name, user.name])


def test_a_second_run_is_refused_naming_the_first(tmp_path):
    with output_lock(tmp_path / "out.rrd") as path:
        holder = json.loads(path.read_text())
        assert holder["pid"] == os.getpid() and path == tmp_path / ".out.rrd.lock"
        refused = rf"another run is writing this output \(pid {os.getpid()} on host"
        with pytest.raises(OutputError, match=refused), output_lock(tmp_path / "out.rrd"):
            pass
    assert list(tmp_path.iterdir()) == []  # the lock file goes with the run
    with output_lock(tmp_path / "out.rrd"):  # and the output is free again
        pass


def test_a_lock_held_by_another_process_is_refused_and_released_when_it_dies(tmp_path, caplog):
    folder = tmp_path / "demos"
    folder.mkdir()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from cnep.outputs import output_lock\n"
            "with output_lock(sys.argv[1], folder=True):\n    print('held', flush=True); time.sleep(60)",
            str(folder),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        refused = rf"pid {holder.pid} on host .*`kill {holder.pid}`"
        with pytest.raises(OutputError, match=refused), output_lock(folder, folder=True):
            pass
        stale = folder / f".a.mcap.{holder.pid}-abcdef.tmp"
        stale.write_bytes(b"half")  # what the holder leaves when it is killed while writing
    finally:
        holder.kill()
        holder.wait()
    assert (folder / FOLDER_LOCK).exists()  # kill -9 removes nothing, but the OS released its lock
    with caplog.at_level(logging.WARNING), output_lock(folder, folder=True):
        assert not stale.exists()
    assert f"taking over the lock of a run that ended without releasing it (pid {holder.pid}" in caplog.text
    assert list(folder.iterdir()) == []


def test_a_file_that_is_not_a_lock_is_never_written_into(tmp_path):
    mine = lock_path(tmp_path / "ckpt", folder=False)
    mine.write_text("my notes")
    with pytest.raises(OutputError, match="is not a cnep lock file"), output_lock(tmp_path / "ckpt"):
        pass
    assert mine.read_text() == "my notes"


def test_a_lock_in_a_missing_folder_is_an_os_error_naming_it(tmp_path):
    with pytest.raises(OSError) as raised, output_lock(tmp_path / "missing" / "out.rrd"):
        pass
    assert raised.value.errno == errno.ENOENT and raised.value.filename == str(tmp_path / "missing")
    assert not (tmp_path / "missing").exists()
