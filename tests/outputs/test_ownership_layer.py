"""cnep.outputs' ownership: files recorded by the command that wrote them, replaced only by that command and only while
unchanged, checked again at the moment of replacing; folders replaced as a whole or emptied file by file."""

from __future__ import annotations

import os
import signal

import pytest

from cnep.outputs import (
    NotOwned,
    OutputError,
    foreign_files,
    is_recorded,
    output_file,
    publish_folder,
    record_written,
    recorded_by,
    recover_set_aside,
    remove_owned,
    signals_held,
    staged,
    write_output,
    writer,
    writing_as,
)
from tests.outputs.test_outputs import dead_pid


def test_the_outermost_command_records_its_stages_files(tmp_path):
    assert writer() is None
    with writing_as("demo"), writing_as("ingest") as command:  # the demo's ingest writes the demo's files
        assert command == "demo" and writer() == "demo"
        write_output(tmp_path / "a.mcap", b"a")
    assert writer() is None
    assert is_recorded(tmp_path / "a.mcap", "demo") and not is_recorded(tmp_path / "a.mcap", "ingest")
    with pytest.raises(RuntimeError, match="outside `cnep.outputs.writing_as`"):
        record_written([tmp_path / "a.mcap"])


def test_the_workers_a_command_starts_write_as_it(tmp_path):
    import subprocess
    import sys

    code = "import sys; from cnep.outputs import write_output; write_output(sys.argv[1], b'w')"
    with writing_as("extract"):
        subprocess.run([sys.executable, "-c", code, str(tmp_path / "w.mcap")], check=True)
    assert is_recorded(tmp_path / "w.mcap", "extract")


def test_a_file_that_appears_while_a_command_writes_is_kept_and_nothing_is_renamed(tmp_path):
    with writing_as("ingest"):
        write_output(tmp_path / "b.json", b"old")  # the command's own: replaced
        appeared = pytest.raises(OutputError, match=r"a.mcap: this file appeared while `cnep ingest` ran")
        with appeared, staged(record=True) as staging:
            staging.write(tmp_path / "b.json", b"new")
            staging.write(tmp_path / "a.mcap", b"cnep's")
            (tmp_path / "a.mcap").write_bytes(b"mine")  # the user's, meanwhile
    assert (tmp_path / "a.mcap").read_bytes() == b"mine" and (tmp_path / "b.json").read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["a.mcap", "b.json"]
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    with writing_as("demo"), pytest.raises(OutputError, match="b.json: this file appeared"):
        write_output(tmp_path / "b.json", b"new")  # another command's file is never its own
    with writing_as("ingest"):
        write_output(tmp_path / "b.json", b"new")  # its own, unchanged: replaced
        (tmp_path / "b.json").write_bytes(b"edited")  # edited since: no longer its own
        with pytest.raises(OutputError, match="b.json: this file appeared"):
            write_output(tmp_path / "b.json", b"newer")
    assert (tmp_path / "b.json").read_bytes() == b"edited"


@writing_as("repair")
def test_a_full_disk_in_an_output_file_names_the_output(tmp_path):
    import errno

    with pytest.raises(OSError) as raised, output_file(tmp_path / "fixed.mcap") as staged_path:
        raise OSError(errno.ENOSPC, "No space left on device", str(staged_path))
    assert raised.value.filename == str(tmp_path / "fixed.mcap") and list(tmp_path.iterdir()) == []


def checkpoint(folder, tag: bytes = b"1"):
    """A folder of two files `train` recorded writing."""
    folder.mkdir(parents=True)
    with writing_as("train"):
        write_output(folder / "config.json", b"{}" + tag)
        write_output(folder / "model.safetensors", b"w" + tag)
    return folder


def names(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_a_folder_is_replaced_only_when_everything_in_it_is_the_commands(tmp_path):
    owns = recorded_by("train")
    out, work = checkpoint(tmp_path / "ckpt"), checkpoint(tmp_path / "work", b"2")
    (out / "sub").mkdir()
    (out / "sub" / "thesis.tex").write_text("mine")  # appeared while the run worked
    with pytest.raises(NotOwned) as raised:
        publish_folder(work, out, owns)
    assert raised.value.path == out / "sub" / "thesis.tex"
    assert (out / "sub" / "thesis.tex").read_text() == "mine" and (out / "config.json").read_bytes() == b"{}1"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt", "work"]  # put back: nothing set aside is left
    (out / "sub" / "thesis.tex").unlink()
    publish_folder(work, out, owns)
    assert (out / "config.json").read_bytes() == b"{}2" and sorted(p.name for p in tmp_path.iterdir()) == ["ckpt"]


def test_emptying_a_folder_takes_only_the_commands_files(tmp_path):
    out = checkpoint(tmp_path / "d")
    (out / "mine").mkdir()
    (out / "mine" / "notes.txt").write_text("mine")
    with writing_as("ingest"):
        write_output(out / "mine" / "a.mcap", b"ingest's")
    assert foreign_files(out, recorded_by("train")) == [out / "mine" / "a.mcap", out / "mine" / "notes.txt"]
    assert remove_owned(out, recorded_by("train")) == [out / "mine" / "a.mcap", out / "mine" / "notes.txt"]
    assert names(out) == ["mine", "mine/.cnep-record.json", "mine/a.mcap", "mine/notes.txt"]
    assert is_recorded(out / "mine" / "a.mcap", "ingest")  # its folder's record stays with it


def test_a_folder_set_aside_by_a_killed_run_is_restored_or_removed_and_any_other_left_alone(tmp_path):
    owns = recorded_by("train")
    out = tmp_path / "ckpt"
    aside = checkpoint(tmp_path / f".ckpt.replaced-{dead_pid()}-abcdef")  # killed before the new one took its name
    users = tmp_path / ".ckpt.replaced"  # the user's, named alike
    users.mkdir()
    (users / "thesis.tex").write_text("mine")
    live = checkpoint(tmp_path / f".ckpt.replaced-{os.getpid()}-abcdef")  # a run that still runs
    recover_set_aside(out, owns)
    assert (out / "config.json").read_bytes() == b"{}1" and not aside.exists()
    checkpoint(aside, b"old")  # killed after the new one took its name
    foreign = checkpoint(tmp_path / f".ckpt.replaced-{dead_pid()}-fedcba")
    (foreign / "thesis.tex").write_text("mine")
    recover_set_aside(out, owns)
    assert not aside.exists() and (out / "config.json").read_bytes() == b"{}1"
    assert (users / "thesis.tex").read_text() == "mine" and (foreign / "thesis.tex").read_text() == "mine"
    assert live.is_dir() and (live / "config.json").is_file()


def test_signals_held_take_effect_when_the_block_ends(ctrl_c_raises):
    done = []
    with pytest.raises(KeyboardInterrupt), signals_held():
        signal.raise_signal(signal.SIGINT)  # to this thread, now: Ctrl-C at this point
        done.append("renamed")
        done.append("recorded")
    assert done == ["renamed", "recorded"]


class Killed(BaseException):
    """A process killed at this point (kill -9): nothing after it runs, no clean-up but the interpreter's."""


@pytest.mark.parametrize("at", ["rename", "second record"])
def test_a_file_replaced_stays_the_commands_whichever_version_a_kill_leaves(tmp_path, monkeypatch, at):
    import cnep.outputs.record as record

    target = tmp_path / "a.mcap"
    first = record.record_entries
    calls = []

    def record_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise Killed
        return first(*args, **kwargs)

    def killed(*args):
        raise Killed

    with writing_as("ingest"):
        write_output(target, b"old")
        with monkeypatch.context() as patched, pytest.raises(Killed):
            if at == "rename":
                patched.setattr(record.os, "replace", killed)  # after the record names both, before the rename
            else:
                patched.setattr(record, "record_entries", record_once)  # after the rename, before the final record
            write_output(target, b"new")
    assert target.read_bytes() == (b"old" if at == "rename" else b"new")
    assert is_recorded(target, "ingest")
