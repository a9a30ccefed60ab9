"""An output folder assembled under a temporary name beside it and renamed into place when complete.

    with assembled_folder(out, refuse, owns) as work:  # `.OUT.<pid>-<random>.tmp`, the run holding the lock on OUT
        ...write everything into work...
    # OUT is the complete folder; on any error (Ctrl-C included) the work folder goes and OUT is as it was

The work folder is new and unique to the run (made, never reused), so it holds only what the run wrote. An existing
OUT, replaced only where the caller's `refuse` lets it (`contract.refuse_existing`), is set aside under a name unique
to the run and checked again there before the new folder takes its name: `owns` says what in it the command may
replace (cnep.outputs.publish_folder); a file that appeared in it meanwhile keeps it in place. A run killed in
between leaves the set-aside folder, which the next run into OUT puts right (cnep.outputs.recover_set_aside), and
its work folder, which the next run removes (`remove_stale_work`). `cnep export` and `cnep to-lerobot` write their
folders so; `cnep train` publishes its resumable work folder with cnep.outputs.publish_folder too.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

from cnep.outputs import (
    NotOwned,
    Owns,
    is_stale_temporary,
    naming,
    output_lock,
    publish_folder,
    recorded_by,
    recover_set_aside,
    temporary_path,
    writer,
)
from cnep.pipeline.contract import check_writable_folder, output_folder
from cnep.pipeline.errors import PipelineError

log = logging.getLogger(__name__)


def remove_stale_work(out: Path) -> None:
    """Remove the work folders that killed runs into `out` left beside it (their process no longer runs)."""
    for work in out.parent.glob(f".{out.name}.*.tmp"):
        if work.is_dir() and not work.is_symlink() and is_stale_temporary(work):
            log.warning("%s: removing the work folder of a run that was stopped", work)
            shutil.rmtree(work, ignore_errors=True)


@contextlib.contextmanager
def said_of_output(work: Path, out: Path) -> Iterator[None]:
    """An OSError in the block naming a file in the work folder `work` is raised naming the file of `out` it was to
    become (the work folder's name is the run's own, and gone once the run fails)."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None or not Path(exc.filename).is_relative_to(work):
            raise
        raise OSError(exc.errno, exc.strerror, str(out / Path(exc.filename).relative_to(work))) from None


@contextlib.contextmanager
def assembled_folder(out: Path, refuse: Callable[[], None], owns: Owns | None = None) -> Iterator[Path]:
    """A new work folder for `out` (module docstring), renamed to `out` when the block completes.

    `refuse` raises when `out` may not be replaced; it is called again here, under the lock on `out`, and `owns`
    (default: the files the command writing recorded) decides again when the new folder replaces it."""
    owns = recorded_by(writer()) if owns is None else owns
    with output_folder(out.parent), output_lock(out):
        check_writable_folder(out.parent)
        recover_set_aside(out, owns)
        refuse()
        remove_stale_work(out)
        work = temporary_path(out)
        work.mkdir()
        try:
            with naming(out), said_of_output(work, out):  # a full disk: said of OUT, not of the work folder
                yield work
            publish_folder(work, out, owns)
        except NotOwned as exc:
            shutil.rmtree(work, ignore_errors=True)
            raise PipelineError(
                f"{exc.path}: this appeared in {out} (--out) while `cnep {writer()}` ran, and a command replaces a "
                f"folder only when it wrote every file in it; cnep never deletes your own files: {out} is kept as it "
                f"was; move the file away and run the command again"
            ) from None
        except BaseException:
            shutil.rmtree(work, ignore_errors=True)
            raise
