"""One run at a time per output: an exclusive lock held for the run, naming its holder to anyone refused.

The lock is an OS-level lock (flock, through the `filelock` library) on a small file: `.<name>.lock` beside
a file output (a checkpoint folder counts as one: it is renamed into place), `.cnep-folder.lock` inside a folder
that several files are written into. The operating system releases it when its holder dies, however it
dies; the file itself says who holds it (process id, host, command, start time), so a refused run can
name the live one, and a run that finds the file of a dead holder takes it over with a note. The file is
removed when the run ends.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import socket
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from cnep.outputs.atomic import naming, remove_stale_temporaries
from cnep.outputs.errors import OutputError

log = logging.getLogger(__name__)

FOLDER_LOCK = ".cnep-folder.lock"  # not `.cnep.lock`: that is the lock beside an output named `cnep`
_SIGNATURE = b'{"pid": '  # how the lock file's JSON starts (_holder's first key)
_HOLDER_BYTES = 4096  # the most of a lock file read: a holder is a few hundred bytes (its command cut at 300)


def is_lock_name(name: str) -> bool:
    """True for the name of a lock file (`lock_path`)."""
    return name == FOLDER_LOCK or (name.startswith(".") and name.endswith(".lock"))


def is_cnep_lock(path: Path) -> bool:
    """True for a lock file a cnep run wrote (`output_lock`): a lock file's name, and empty or naming its holder."""
    if not is_lock_name(path.name) or path.is_symlink() or not path.is_file():
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(len(_SIGNATURE))
    except OSError:
        return False
    return head in (b"", _SIGNATURE)


def lock_path(output: Path, folder: bool) -> Path:
    """Where the lock of `output` lives: inside it for a folder of outputs, beside it for a file (or checkpoint)."""
    return output / FOLDER_LOCK if folder else output.parent / f".{output.name}.lock"


def _holder() -> dict:
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "command": " ".join([os.path.basename(sys.argv[0]) or "python", *sys.argv[1:]])[:300],
        "started": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def _read_holder(path: Path) -> dict | None:
    """The holder a lock file names: {} when it says nothing readable (yet), None when there is no file."""
    try:
        with open(path, "rb") as f:
            text = f.read(_HOLDER_BYTES).decode("utf-8", errors="replace").strip()
    except FileNotFoundError:
        return None
    except OSError:
        return {}
    try:
        holder = json.loads(text)
    except (ValueError, RecursionError):  # a file planted as the lock says nothing a holder would
        return {}
    return holder if isinstance(holder, dict) else {}


def _refuse_foreign(path: Path) -> None:
    """OutputError if a file that is no cnep lock file sits where the lock goes (flock would write into it)."""
    if path.exists() and not path.is_file() and not path.is_dir():  # a pipe: opening it would wait for a writer
        raise OutputError(f"{path}: this is where the output's lock file goes, and it is no file; move it away")
    try:
        with open(path, "rb") as f:
            head = f.read(len(_SIGNATURE))
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        if path.is_dir():
            raise OutputError(f"{path}: a folder is where the output's lock file goes; move it away") from None
        return
    if head and head != _SIGNATURE:
        raise OutputError(
            f"{path}: this file is where the output's lock file goes and is not a cnep lock file; move it "
            f"away, or choose another output"
        )


def _describe(holder: dict) -> str:
    if not holder:
        return "a process that has not said who it is yet"
    return (
        f"pid {holder.get('pid')} on host {holder.get('host')}, `{holder.get('command')}`, "
        f"since {holder.get('started')}"
    )


@contextlib.contextmanager
def output_lock(
    output: str | os.PathLike, folder: bool = False, names: Iterable[str] | None = None, clean: bool = True
) -> Iterator[Path]:
    """Hold the exclusive lock on `output` for the block; yields the lock file's path.

    folder: `output` is a folder that the run writes files into (it must exist); else a file or a
    checkpoint folder, whose parent must exist. Another run holding the lock -> OutputError naming it.
    With `clean`, once the lock is held and again when it is released, the temporary files of dead
    processes are removed: everywhere under a folder output, or those of `names` (default: the output's
    own name) beside a file output.
    """
    from filelock import FileLock, Timeout  # a dependency of torch, pinned in pyproject.toml

    output = Path(output)
    path = lock_path(output, folder)
    names = [output.name] if names is None else list(names)
    if not path.parent.is_dir():  # filelock would create it, and leave it behind
        raise OSError(errno.ENOENT, "no such folder", str(path.parent))
    _refuse_foreign(path)  # before flock opens it: the holder writes into its lock file
    lock = FileLock(str(path), timeout=0)
    try:
        lock.acquire()
    except Timeout:
        holder = _read_holder(path) or {}
        same_host = holder.get("host") == socket.gethostname()
        stop = f", or stop it (`kill {holder['pid']}`) and run again" if same_host and "pid" in holder else ""
        raise OutputError(
            f"{output}: another run is writing this output ({_describe(holder)}); wait for it to finish{stop}"
        ) from None
    except OSError as exc:  # the folder cannot be written: name it, not the lock file the user never asked for
        raise OSError(exc.errno, exc.strerror, str(path.parent)) from None
    try:
        previous = _read_holder(path)
        if previous and previous.get("pid") != os.getpid():
            log.warning(
                "%s: taking over the lock of a run that ended without releasing it (%s)", output, _describe(previous)
            )
        with naming(output):  # a full disk: say so of the output the user asked for, not of the lock file
            path.write_text(json.dumps(_holder()) + "\n", encoding="utf-8")
        if clean:
            _clean(output, folder, names)
        yield path
    finally:
        try:
            if clean:  # what workers stopped with the run left (a worker killed while writing)
                _clean(output, folder, names)
        finally:
            with contextlib.suppress(OSError):
                path.unlink()  # while still holding it: a waiting run then locks a new file, never this one
            lock.release()


def _clean(output: Path, folder: bool, names: list[str]) -> None:
    with contextlib.suppress(OSError):
        if folder:
            remove_stale_temporaries(output, recursive=True)
            remove_stale_locks(output, keep=lock_path(output, folder))
        else:
            remove_stale_temporaries(output.parent, names)


def remove_stale_locks(folder: Path, keep: Path | None = None) -> int:
    """Remove the lock files under `folder` (all depths) that no live run holds, except `keep`: the leftovers of
    runs into outputs inside it that were killed. Returns how many were removed."""
    from filelock import FileLock, Timeout

    removed = 0
    for path in folder.rglob(".*.lock"):
        if path == keep or not is_lock_name(path.name) or not path.is_file():
            continue
        with contextlib.suppress(OutputError):
            _refuse_foreign(path)
            lock = FileLock(str(path), timeout=0)
            try:
                lock.acquire()
            except (Timeout, OSError):
                continue  # held: a live run (an output inside this one, written now)
            try:
                path.unlink()
                removed += 1
            finally:
                lock.release()
    if removed:
        log.warning("%s: removed %d lock file(s) left by interrupted runs", folder, removed)
    return removed
