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
import signal
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)

TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[0-9a-f]{6}\.tmp$")


def temporary_path(target: Path) -> Path:
    """A new temporary name for `target`, beside it: `.<name>.<pid>-<6 hex digits>.tmp`."""
    return target.parent / f".{target.name}.{os.getpid()}-{secrets.token_hex(3)}.tmp"


def named(exc: OSError, target: Path) -> OSError:
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
        renamed = named(exc, Path(target))
        if renamed is exc:
            raise
        raise renamed from None


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
            raise named(exc, target) from None

    def write(self, target: str | os.PathLike, data: bytes, keep: bool = True) -> Path:
        """Write `data` under a temporary name beside `target` (`open`); returns that name."""
        with self.open(target, keep) as stream:
            stream.write(data)
        return self._staged[-1][0]


@contextlib.contextmanager
def staged(record: bool = False) -> Iterator[Staging]:
    """Stage several files (`Staging.open`, `write`, `path`); when the block completes they are renamed into place,
    in the order staged; on any exception (Ctrl-C and SIGTERM included) every staged file is removed and no target
    changes. Targets' folders must exist.

    With `record`, they are outputs of the command writing (`cnep.outputs.record.writer`): each target must then be
    absent or that command's recorded, unchanged file at the moment of the rename (else OutputError, and nothing is
    renamed), and the targets are added to their folders' records with the renames (`record.rename_recorded`)."""
    staging = Staging()
    try:
        yield staging
        kept = [(tmp, target) for tmp, target in staging._staged if target is not None]
        if record:
            from cnep.outputs.record import rename_recorded, required_writer

            rename_recorded(kept, required_writer())
        for tmp, target in [] if record else kept:
            try:
                os.replace(tmp, target)
            except OSError as exc:
                raise named(exc, target) from None
    finally:
        for tmp, _ in staging._staged:
            _remove(tmp)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive in the block take effect when it ends, so that what it does is done whole (a
    rename and its record). Only the main thread can hold them, and only where Python installed their handlers."""
    signals = (signal.SIGINT, signal.SIGTERM)
    if threading.current_thread() is not threading.main_thread() or None in map(signal.getsignal, signals):
        yield
        return
    received: list[int] = []
    saved = {signum: signal.signal(signum, lambda signum, frame: received.append(signum)) for signum in signals}
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        if received:
            signal.raise_signal(received[0])  # its own handler runs now


@contextlib.contextmanager
def output_file(target: str | os.PathLike) -> Iterator[Path]:
    """A temporary name for the writing command's output `target` (a writer that takes a path writes it there),
    renamed to `target` and recorded when the block completes (`staged(record=True)`)."""
    target = Path(target)
    with staged(record=True) as staging:
        tmp = staging.path(target)
        try:
            yield tmp
        except OSError as exc:  # a full disk while writing the temporary name: say so of the file the user asked for
            if exc.filename is None or not TEMPORARY.match(Path(exc.filename).name):
                raise
            raise OSError(exc.errno, exc.strerror, str(target)) from None


def write_output(target: str | os.PathLike, data: bytes) -> Path:
    """Write `data` as the writing command's output `target` (`staged(record=True)`); returns the target."""
    with staged(record=True) as staging:
        staging.write(target, data)
    return Path(target)


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


def _target_name(name: str) -> str:
    """The name a temporary file is for, through temporaries of temporaries (a writer that writes atomically itself,
    given the temporary name of `output_file`)."""
    while (match := TEMPORARY.match(name)) is not None:
        name = match["name"]
    return name


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
        if match is None or (wanted is not None and _target_name(path.name) not in wanted) or not path.is_file():
            continue
        if is_stale_temporary(path):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += 1
    if removed:
        log.warning("%s: removed %d temporary file(s) left by an interrupted run", folder, removed)
    return removed
