"""A folder output replaced as a whole (a checkpoint, a policy folder) or emptied (the demo's): only what its command
owns goes (`Owns`: by default the record, `cnep.outputs.record.recorded_by`), checked at the moment it goes.

    publish_folder(work, out, owns)   # the finished `work` becomes `out`; an existing `out` is set aside, checked,
                                      # and emptied of what the command owns

The old output is first renamed to `.<name>.replaced-<pid>-<6 hex>` beside it (a name unique to the run, reserved by
creating it, so an existing folder of that name is never reused), then checked there: anything in it the command
does not own (a file that appeared while the run worked) puts it back and raises `NotOwned`. Only then does the new
one take its name, and the old one is emptied file by file, each file checked again as it goes (`remove_owned`);
what is left, a folder included, stays. A run killed in between leaves the set-aside folder, which the next run
into `out` restores (no `out`) or empties, checked the same way (`recover_set_aside`); one whose process still runs,
or that holds what the command does not own, is left alone, and so is any folder not named this way.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import secrets
from collections.abc import Iterable
from pathlib import Path

from cnep.outputs.atomic import pid_alive, signals_held
from cnep.outputs.errors import OutputError
from cnep.outputs.record import RECORD_FILE, Owns, foreign_files, is_bookkeeping, record_entries

log = logging.getLogger(__name__)

ASIDE = re.compile(r"^\.(?P<name>.+)\.replaced-(?P<pid>\d+)-[0-9a-f]{6}$")


class NotOwned(OutputError):
    """An output holds `path`, which its command does not own; the output was left as it was."""

    def __init__(self, path: Path, output: Path):
        self.path, self.output = path, output
        super().__init__(f"{path}: {output} holds this, which the command did not write; {output} was left as it was")


def set_aside(out: Path, owns: Owns) -> Path:
    """Rename the folder `out` to a new name unique to the run beside it and return that name, once nothing in it is
    foreign (`owns`); NotOwned (and `out` as it was) otherwise."""
    if out.is_symlink() or not out.is_dir():
        raise NotOwned(out, out)
    aside = out.parent / f".{out.name}.replaced-{os.getpid()}-{secrets.token_hex(3)}"
    os.mkdir(aside)  # reserved: FileExistsError rather than reuse a folder of that name
    try:
        os.rename(out, aside)  # onto the empty folder just made
    except OSError:
        os.rmdir(aside)
        raise
    foreign = foreign_files(aside, owns)
    if foreign:
        os.rename(aside, out)  # back: nothing changed
        raise NotOwned(out / foreign[0].relative_to(aside), out)
    return aside


def publish_folder(work: Path, out: Path, owns: Owns) -> None:
    """Rename the finished folder `work` to `out`; an existing `out` is set aside (`set_aside`: NotOwned if it holds
    what the command does not own, and then nothing changes) and emptied of what the command owns afterwards."""
    with signals_held():  # out is always the old folder or the new one
        aside = set_aside(out, owns) if os.path.lexists(out) else None
        try:
            os.rename(work, out)
        except OSError:
            if aside is not None:
                os.rename(aside, out)
            raise
    if aside is not None:
        discard(aside, owns)


def remove_owned(root: Path, owns: Owns, keep: Iterable[Path] = ()) -> list[Path]:
    """Delete what under `root` the command owns (each file checked as it goes) and cnep's bookkeeping, then the
    folders this leaves empty (not `root`); `keep` stays. Returns what is left, files and links, sorted."""
    kept = set(map(Path, keep))
    left = []
    for folder, dirs, files in os.walk(root, topdown=False):
        here = Path(folder)
        links = [d for d in dirs if os.path.islink(os.path.join(folder, d))]
        entries = [here / name for name in [*files, *links] if here / name not in kept and name != RECORD_FILE]
        owned = [p for p in entries if not p.is_symlink() and (owns(root, p) or is_bookkeeping(p))]
        for path in owned:  # checked together first: a record (or manifest) says what the files beside it are
            path.unlink()
        left += [p for p in entries if p not in owned]
        record = here / RECORD_FILE
        if record.is_file() and not record.is_symlink():  # it goes with the last file it could name
            if any(p.parent == here for p in left):
                record_entries({}, forget=owned)
            else:
                record.unlink()
        if here != root:
            with contextlib.suppress(OSError):
                here.rmdir()  # only an empty folder goes
    return sorted(left)


def discard(folder: Path, owns: Owns) -> None:
    """Empty `folder` of what the command owns (`remove_owned`) and remove it; what is left stays, with a warning."""
    left = remove_owned(folder, owns)
    with contextlib.suppress(OSError):
        folder.rmdir()
    if left:
        log.warning("%s: kept, it holds %s, which the command did not write", folder, left[0])


def recover_set_aside(out: Path, owns: Owns) -> None:
    """After a run killed while publishing (`publish_folder`): each folder it set `out` aside in, whose process no
    longer runs and that holds only what the command owns, is put back if `out` is missing, else emptied and
    removed. Call it holding the lock on `out`."""
    for aside in sorted(out.parent.glob(f".{out.name}.replaced-*")):
        match = ASIDE.match(aside.name)
        if match is None or match["name"] != out.name or aside.is_symlink() or not aside.is_dir():
            continue
        if pid_alive(int(match["pid"])) or foreign_files(aside, owns):
            log.warning("%s: left alone, it is not a folder a finished or stopped run of this command set aside", aside)
            continue
        if os.path.lexists(out):
            log.warning("%s: removing the output a finished run replaced", aside)
            discard(aside, owns)
        else:
            log.warning("%s: a run was stopped while replacing %s; restoring the previous output", aside, out)
            os.rename(aside, out)
