"""Files written under a temporary name unique to the run, renamed into place when complete.

The temporary name is `.<name>.<pid>-<random>.tmp` beside the target: hidden, in the same folder (so the
rename is atomic), and naming the process that writes it, so that a later run can tell the leftovers of
a killed run (its process is gone) from a file another live process is still writing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import secrets
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)

TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[0-9a-f]{6}\.tmp$")


def temporary_path(target: Path) -> Path:
    """A new temporary name for `target`, beside it: `.<name>.<pid>-<6 hex digits>.tmp`."""
    return target.parent / f".{target.name}.{os.getpid()}-{secrets.token_hex(3)}.tmp"


def _named(exc: OSError, target: Path) -> OSError:
    """`exc` naming `target` when it names no file (a write or fsync on a full disk says only "No space left")."""
    if exc.filename is not None or exc.errno is None:
        return exc
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(target))


@contextlib.contextmanager
def naming(target: str | os.PathLike) -> Iterator[None]:
    """An OSError in the block that names no file (a write on a full disk, over a quota) is raised naming `target`."""
    try:
        yield
    except OSError as exc:
        named = _named(exc, Path(target))
        if named is exc:
            raise
        raise named from None


class Staging:
    """Files written under temporary names now and renamed into place together later (`staged`)."""

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path | None]] = []  # (temporary, target or None: discarded at the end)

    def path(self, target: str | os.PathLike, keep: bool = True) -> Path:
        """A temporary name beside `target` for a writer that takes a path (the file must exist at the end); with
        `keep` False the file is an intermediate, removed at the end instead of renamed."""
        tmp = temporary_path(Path(target))
        self._staged.append((tmp, Path(target) if keep else None))
        return tmp

    @contextlib.contextmanager
    def open(self, target: str | os.PathLike, keep: bool = True) -> Iterator[IO[bytes]]:
        """A binary stream on a new temporary file beside `target` (0666 less the umask), flushed and fsynced when
        the block ends. An OSError that names no file (a full disk, a quota) is raised naming `target`."""
        target = Path(target)
        tmp = self.path(target, keep)
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except OSError as exc:  # the folder cannot be written: say so of the file the user asked for
            raise OSError(exc.errno, exc.strerror, str(target)) from None
        try:
            with os.fdopen(fd, "wb") as stream:
                yield stream
                stream.flush()
                os.fsync(stream.fileno())
        except OSError as exc:
            raise _named(exc, target) from None

    def write(self, target: str | os.PathLike, data: bytes, keep: bool = True) -> Path:
        """Write `data` under a temporary name beside `target` (`open`); returns that name."""
        with self.open(target, keep) as stream:
            stream.write(data)
        return self._staged[-1][0]


@contextlib.contextmanager
def staged(record: bool = False) -> Iterator[Staging]:
    """Stage several files (`Staging.open`, `write`, `path`); when the block completes they are renamed into place,
    in the order staged, and with `record` added to their folders' records (`cnep.outputs.record`); on any exception
    (Ctrl-C and SIGTERM included) every staged file is removed and no target changes. Targets' folders must exist."""
    staging = Staging()
    try:
        yield staging
        for tmp, target in staging._staged:
            if target is not None:
                try:
                    os.replace(tmp, target)
                except OSError as exc:
                    raise _named(exc, target) from None
        if record:
            from cnep.outputs.record import record_written

            record_written(target for _, target in staging._staged if target is not None)
    finally:
        for tmp, _ in staging._staged:
            _remove(tmp)


@contextlib.contextmanager
def atomic_file(target: str | os.PathLike) -> Iterator[IO[bytes]]:
    """A binary stream on a temporary file beside `target`, renamed to `target` when the block completes and
    removed on any exception, leaving `target` as it was (`staged` with one file)."""
    with staged() as staging, staging.open(target) as stream:
        yield stream


def write_atomically(target: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `target` through `atomic_file`; returns the target."""
    with atomic_file(target) as stream:
        stream.write(data)
    return Path(target)


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def pid_alive(pid: int) -> bool:
    """True if a process with this id runs on this machine (a process of another user counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def is_stale_temporary(path: Path) -> bool:
    """True for a temporary file (`temporary_path`) whose writing process no longer runs."""
    match = TEMPORARY.match(path.name)
    return match is not None and not pid_alive(int(match["pid"]))


def remove_stale_temporaries(folder: Path, names: Iterable[str] | None = None, recursive: bool = False) -> int:
    """Remove the temporary files of runs that no longer run: those of `names` in `folder` (None: of any name),
    or with `recursive` everywhere under `folder`. Returns how many were removed (a note is logged)."""
    if not folder.is_dir():
        return 0
    wanted = None if names is None else set(names)
    candidates = folder.rglob(".*.tmp") if recursive else folder.glob(".*.tmp")
    removed = 0
    for path in candidates:
        match = TEMPORARY.match(path.name)
        if match is None or (wanted is not None and match["name"] not in wanted) or not path.is_file():
            continue
        if is_stale_temporary(path):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += 1
    if removed:
        log.warning("%s: removed %d temporary file(s) left by an interrupted run", folder, removed)
    return removed
