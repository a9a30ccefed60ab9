"""The record of what cnep wrote in a folder, and which command wrote it: what that command may replace or delete.

Every folder a command writes outputs into holds `.cnep-record.json`, naming the files of that folder the
command wrote, each with its size (bytes), sha256 and the command (a `cnep` subcommand's name):

    {"format_version": 2, "files": {"a.mcap": {"size": 51234, "sha256": "9f2c...", "command": "ingest"}}}

A file is a command's (`is_recorded`) only while its folder's record names it, written by that command, with the
same size and sha256: a user's file at that name, cnep's file edited since, or another command's output is not. A
folder without a record (or with a record of another format) holds nothing of any command's. The record names only
the files of its own folder (no separators), so a folder and its record travel together (moved, copied, renamed).

The command writing is the one whose stage runs (`writing_as`); the stages it runs for itself write as it (the
demo's ingest writes the demo's files), and so do its worker processes, which inherit it through the environment
(`WRITER_ENV`). The record is updated atomically under an OS lock on the folder, so concurrent writers (worker
processes) never lose each other's entries; `staged(record=True)` renames and records together (`rename_recorded`),
so that a process killed at any moment leaves no output of its own unrecorded.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path

from cnep.outputs.atomic import TEMPORARY, is_stale_temporary, named, signals_held, write_atomically
from cnep.outputs.errors import OutputError
from cnep.outputs.lock import is_cnep_lock

RECORD_FILE = ".cnep-record.json"
RECORD_VERSION = 2
WRITER_ENV = "CNEP_WRITER"  # the command writing now (`writing_as`), for this process and the workers it starts
_CHUNK = 1 << 20  # bytes read at a time while hashing
MAX_RECORD_BYTES = 16 << 20  # the largest record read (bytes): about 150,000 files' entries

Owns = Callable[[Path, Path], bool]  # (the folder being replaced or emptied, a file under it) -> the command's own


@contextlib.contextmanager
def writing_as(command: str) -> Iterator[str]:
    """The block's outputs are recorded as written by `command`, unless a command already writes (the demo running
    `ingest` for itself: its files are the demo's); yields the command writing."""
    outer = os.environ.get(WRITER_ENV)
    if outer:
        yield outer
        return
    os.environ[WRITER_ENV] = command
    try:
        yield command
    finally:
        os.environ.pop(WRITER_ENV, None)


def writer() -> str | None:
    """The command writing now (`writing_as`); None outside one."""
    return os.environ.get(WRITER_ENV) or None


def required_writer() -> str:
    """The command writing now; RuntimeError outside one (a stage that never said which command it is: a bug)."""
    command = writer()
    if command is None:
        raise RuntimeError("an output is recorded outside `cnep.outputs.writing_as`: no command to record it for")
    return command


def file_entry(path: Path, command: str) -> dict:
    """{"size": bytes, "sha256": hex digest, "command": `command`} of the file at `path`."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_CHUNK):
            digest.update(block)
    return {"size": os.path.getsize(path), "sha256": digest.hexdigest(), "command": command}


def read_record(folder: Path) -> dict[str, dict] | None:
    """The files `folder`'s record names ({name: entry}); None when the folder has no readable record (none, not a
    regular file, larger than MAX_RECORD_BYTES, or not a record)."""
    path = Path(folder) / RECORD_FILE
    try:
        if not path.is_file():  # a pipe planted there would make open() wait for a writer
            return None
        with open(path, "rb") as f:
            raw = f.read(MAX_RECORD_BYTES + 1)
        if len(raw) > MAX_RECORD_BYTES:
            return None
        data = json.loads(raw.decode("utf-8"))
    except (OSError, ValueError, RecursionError):  # RecursionError: a planted record nested too deep to parse
        return None
    if not isinstance(data, dict) or data.get("format_version") != RECORD_VERSION:
        return None
    files = data.get("files")
    if not isinstance(files, dict):
        return None
    return {name: entry for name, entry in files.items() if isinstance(entry, dict)}


def is_recorded(path: Path, command: str, record: dict[str, dict] | None = None) -> bool:
    """True if `path` is a regular file that its folder's record (or `record`, read from it) names as written by
    `command`, with the same size and sha256 (or those of the file it replaces, while a rename is under way:
    `rename_recorded`): a file that command wrote there and nobody changed since."""
    path = Path(path)
    record = read_record(path.parent) if record is None else record
    entry = (record or {}).get(path.name)
    if entry is None or entry.get("command") != command or path.is_symlink() or not path.is_file():
        return False
    versions = [entry, entry.get("previous") or {}]
    size = path.stat().st_size
    if all(version.get("size") != size for version in versions):
        return False  # no need to read it
    digest = file_entry(path, command)["sha256"]
    return any(version.get("size") == size and version.get("sha256") == digest for version in versions)


def recorded_by(command: str) -> Owns:
    """Ownership by the record: a file is the command's when its folder's record names it, unchanged, as its."""
    return lambda root, path: is_recorded(path, command)


def is_bookkeeping(path: Path) -> bool:
    """cnep's own bookkeeping, which goes with the folder it keeps: a record, the temporary file of a process that
    no longer runs, a cnep lock file."""
    if path.is_symlink() or not path.is_file():
        return False
    if path.name == RECORD_FILE:
        return True
    if TEMPORARY.match(path.name):
        return is_stale_temporary(path)
    return is_cnep_lock(path)


def foreign_files(root: Path, owns: Owns, keep: Iterable[Path] = ()) -> list[Path]:
    """What under the folder `root` (all depths) is not the command's (`owns`), sorted: files and links that are
    neither its own nor cnep's bookkeeping (`keep`: paths that are neither, yet not in question: the run's lock)."""
    kept = set(map(Path, keep))
    found = []
    for folder, dirs, files in os.walk(root):
        for name in [*files, *(d for d in dirs if os.path.islink(os.path.join(folder, d)))]:
            path = Path(folder) / name
            if path not in kept and (path.is_symlink() or not (is_bookkeeping(path) or owns(Path(root), path))):
                found.append(path)
    return sorted(found)


def record_written(paths: Iterable[str | os.PathLike], forget: Iterable[str | os.PathLike] = ()) -> None:
    """Add the files `paths` (complete, just written) to their folders' records as the writing command's (`writer`),
    and drop `forget` from theirs; each record is rewritten atomically under a lock on its folder."""
    command = required_writer()
    record_entries({Path(p): file_entry(Path(p), command) for p in paths}, forget)


def record_entries(
    entries: Mapping[Path, dict], forget: Iterable[str | os.PathLike] = (), previous: Iterable[Path] = ()
) -> None:
    """Set the entries {path: file_entry} in their folders' records and drop `forget` from theirs; for the paths in
    `previous`, the entry they had is kept beside the new one (`is_recorded` takes either) until they are set again."""
    kept = set(map(Path, previous))
    by_folder: dict[Path, tuple[dict[str, dict], list[str]]] = {}
    for path, entry in entries.items():
        by_folder.setdefault(path.parent, ({}, []))[0][path.name] = entry
    for path in map(Path, forget):
        by_folder.setdefault(path.parent, ({}, []))[1].append(path.name)
    for folder, (written, dropped) in by_folder.items():
        with _folder_locked(folder):
            files = read_record(folder) or {}
            for name, entry in written.items():
                old = files.get(name)
                if folder / name in kept and old is not None:
                    entry = {**entry, "previous": {"size": old.get("size"), "sha256": old.get("sha256")}}
                files[name] = entry
            for name in dropped:
                files.pop(name, None)
            body = {"format_version": RECORD_VERSION, "files": dict(sorted(files.items()))}
            write_atomically(folder / RECORD_FILE, (json.dumps(body, indent=1) + "\n").encode())


def rename_recorded(staged: Sequence[tuple[Path, Path]], command: str) -> None:
    """Rename each (temporary file, target) into place as `command`'s output: every target must be absent or the
    command's recorded, unchanged file (else OutputError, and nothing is renamed). The record names each new file
    before its rename, and a file it replaces too until the renames are done, with SIGINT and SIGTERM held off: a
    process killed at any moment (kill -9 included) leaves every target recorded, whichever file it holds."""
    entries = {target: file_entry(tmp, command) for tmp, target in staged}  # hashed before: only the renames wait
    with signals_held():
        refuse_unowned(entries, command)
        replaced = [target for target in entries if os.path.lexists(target)]
        record_entries(entries, previous=replaced)
        for tmp, target in staged:
            try:
                os.replace(tmp, target)
            except OSError as exc:
                raise named(exc, target) from None
        if replaced:
            record_entries({target: entries[target] for target in replaced})


def refuse_unowned(targets: Iterable[Path], command: str) -> None:
    """OutputError naming the first of `targets` that exists and is not `command`'s recorded, unchanged file: what a
    run checks at the moment it replaces its outputs (a file may have appeared since the run began)."""
    for target in targets:
        if os.path.lexists(target) and not is_recorded(target, command):
            raise OutputError(
                f"{target}: this file appeared while `cnep {command}` ran, and it replaces only what `cnep {command}` "
                f"recorded writing; it is kept, and the new output was not written: move it away and run again"
            )


@contextlib.contextmanager
def _folder_locked(folder: Path) -> Iterator[None]:
    """An exclusive OS lock on the folder itself (flock on its descriptor; no lock file), where the OS has one."""
    try:
        import fcntl
    except ImportError:  # no flock (Windows): the record's rename stays atomic, concurrent merges are not serialised
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
