"""An output folder assembled under a temporary name beside it and renamed into place when complete.

    with assembled_folder(out, refuse) as work:  # `.OUT.<pid>-<random>.tmp`, the run holding the lock on OUT
        ...write everything into work...
    # OUT is the complete folder; on any error (Ctrl-C included) the work folder goes and OUT is as it was

An existing OUT, replaced only where the caller's `refuse` lets it (`contract.refuse_existing`), waits as
`.OUT.replaced` while the new folder is renamed in, and is removed after; a run killed in between leaves one of
the two, which the next run into OUT puts right (`recover_replaced`). `cnep export` and `cnep to-lerobot` write
their folders so; `cnep train` publishes its resumable work folder the same way (`publish`).
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

from cnep.outputs import is_stale_temporary, naming, output_lock, temporary_path
from cnep.pipeline.contract import check_writable_folder, output_folder

log = logging.getLogger(__name__)


def replaced_dir(out: Path) -> Path:
    """Where the folder that `--force` replaces waits while the new one is renamed into place (`publish`)."""
    return out.parent / f".{out.name}.replaced"


def recover_replaced(out: Path) -> None:
    """After a run killed while publishing (`publish`): put the replaced folder back if OUT is missing, else drop it.

    Call it holding the lock on OUT."""
    old = replaced_dir(out)
    if not old.is_dir() or old.is_symlink():
        return
    if out.exists():
        log.warning("%s: removing the folder a finished run replaced", old)
        shutil.rmtree(old)
    else:
        log.warning("%s: a run was stopped while replacing %s; restoring the previous one", old, out)
        old.rename(out)


def publish(work: Path, out: Path) -> None:
    """Rename the finished work folder to `out`, replacing an existing `out` (moved aside first, removed after)."""
    old = replaced_dir(out)
    if out.exists():
        out.rename(old)
    work.rename(out)
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old)


def remove_stale_work(out: Path) -> None:
    """Remove the work folders that killed runs into `out` left beside it (their process no longer runs)."""
    for work in out.parent.glob(f".{out.name}.*.tmp"):
        if work.is_dir() and not work.is_symlink() and is_stale_temporary(work):
            log.warning("%s: removing the work folder of a run that was stopped", work)
            shutil.rmtree(work, ignore_errors=True)


@contextlib.contextmanager
def assembled_folder(out: Path, refuse: Callable[[], None]) -> Iterator[Path]:
    """A new work folder for `out` (module docstring), renamed to `out` when the block completes.

    `refuse` raises when `out` may not be replaced; it is called again here, under the lock on `out`."""
    with output_folder(out.parent), output_lock(out):
        check_writable_folder(out.parent)
        recover_replaced(out)
        refuse()
        remove_stale_work(out)
        work = temporary_path(out)
        work.mkdir()
        try:
            with naming(out):  # a full disk: said of the folder the user asked for, not of the work folder
                yield work
            publish(work, out)
        except BaseException:
            shutil.rmtree(work, ignore_errors=True)
            raise
