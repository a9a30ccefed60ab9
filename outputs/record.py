"""The record of what cnep wrote in a folder: what `--force` may replace or delete, and nothing else.

Every folder a command writes outputs into holds `.cnep-record.json`, naming the files of that folder the
command wrote, each with its size (bytes) and sha256:

    {"format_version": 1, "files": {"a.mcap": {"size": 51234, "sha256": "9f2c..."}}}

A file is cnep's (`is_recorded`) only while its folder's record names it with the same size and sha256:
a user's file at that name, or cnep's file edited since, is not. The record names only the files of its
own folder (no separators), so a folder and its record travel together (moved, copied, renamed). It is
updated after the files it names land (`record_written`), atomically and under an OS lock on the folder,
so concurrent writers (worker processes) never lose each other's entries; a process killed between the
two leaves a file unrecorded, which `--force` then refuses (nothing is deleted on a guess).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

from cnep.outputs.atomic import write_atomically

RECORD_FILE = ".cnep-record.json"
RECORD_VERSION = 1
_CHUNK = 1 << 20  # bytes read at a time while hashing
MAX_RECORD_BYTES = 16 << 20  # the largest record read (bytes): about 150,000 files' entries


def file_entry(path: Path) -> dict:
    """{"size": bytes, "sha256": hex digest} of the file at `path`."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_CHUNK):
            digest.update(block)
    return {"size": os.path.getsize(path), "sha256": digest.hexdigest()}


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


def is_recorded(path: Path, record: dict[str, dict] | None = None) -> bool:
    """True if `path` is a regular file that its folder's record (or `record`, read from it) names, with the same
    size and sha256: a file cnep wrote there and nobody changed since."""
    path = Path(path)
    record = read_record(path.parent) if record is None else record
    entry = (record or {}).get(path.name)
    if entry is None or path.is_symlink() or not path.is_file():
        return False
    return entry.get("size") == path.stat().st_size and entry == file_entry(path)


def record_written(paths: Iterable[str | os.PathLike], forget: Iterable[str | os.PathLike] = ()) -> None:
    """Add the files `paths` (complete, just written by cnep) to their folders' records, and drop `forget` from
    theirs; each record is rewritten atomically under a lock on its folder."""
    by_folder: dict[Path, tuple[list[Path], list[str]]] = {}
    for path in map(Path, paths):
        by_folder.setdefault(path.parent, ([], []))[0].append(path)
    for path in map(Path, forget):
        by_folder.setdefault(path.parent, ([], []))[1].append(path.name)
    for folder, (written, dropped) in by_folder.items():
        entries = {path.name: file_entry(path) for path in written}  # hashed before the lock: only the merge waits
        with _folder_locked(folder):
            files = {**(read_record(folder) or {}), **entries}
            for name in dropped:
                files.pop(name, None)
            body = {"format_version": RECORD_VERSION, "files": dict(sorted(files.items()))}
            write_atomically(folder / RECORD_FILE, (json.dumps(body, indent=1) + "\n").encode())


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
