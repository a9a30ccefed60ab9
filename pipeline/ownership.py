"""What cnep may replace or delete: only files a cnep command recorded writing, never a file by its kind alone.

Every command that writes outputs names them in the record of the folder it writes them into
(`cnep.outputs.record`: `.cnep-record.json`, each file with its size and sha256). `--force` replaces an
existing output only when its folder's record names it, unchanged; a folder replaced as a whole (a
checkpoint, the demo's folder) only when every file in it, at every depth, is so named. Anything else
is refused with one line naming it (`pipeline.contract.refuse_existing`), and so is an output that is an
input or contains one (`pipeline.contract.refuse_inputs`).

A folder with no record, written before records existed, is judged by the kind of file the command
writes (`OutputKind.test`: an MCAP file whose header names cnep's recording layer, a checkpoint's files,
a Rerun `.rrd`, ...), and only where every file in it is of that kind: a folder that holds anything
else is refused.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from cnep.outputs import RECORD_FILE, TEMPORARY, is_lock_name, is_recorded, read_record
from cnep.runtime.jsonfile import read_json

CHECKPOINT_FILES = ("config.json", "model.safetensors", "training_log.jsonl")
RRD_MAGIC = b"RRF"  # every Rerun .rrd starts with it (RRF2 in rerun 0.41)


@dataclass(frozen=True)
class OutputKind:
    """A kind of output: what it is called in messages, and a test of an unrecorded file's content (`test`, for
    outputs written before records existed). `folder`, for a folder whose own files are its record (an exported
    policy's manifest), lists the files in it that record does not vouch for."""

    name: str
    test: Callable[[Path], bool]
    folder: Callable[[Path], list[Path]] | None = None

    def __call__(self, path: Path) -> bool:
        return self.test(Path(path))


def _cnep_mcap(path: Path) -> bool:
    from cnep.recordings.constants import LIBRARY_NAME
    from cnep.recordings.container import mcap_library

    return path.is_file() and mcap_library(path) == LIBRARY_NAME


def _json_object(path: Path, keys: Iterable[str] = ()) -> bool:
    try:
        data = read_json(path)
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and all(key in data for key in keys)


def _rrd(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(RRD_MAGIC)) == RRD_MAGIC
    except OSError:
        return False


def _torch_file(path: Path) -> bool:
    """A file torch.save wrote (a zip archive holding `data.pkl`), without unpickling anything."""
    try:
        with zipfile.ZipFile(path) as archive:
            return any(name.endswith("/data.pkl") for name in archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def _bookkeeping(path: Path) -> bool:
    """A temporary file, lock file or record of cnep's output layer."""
    name = path.name
    return path.is_file() and (TEMPORARY.match(name) is not None or is_lock_name(name) or name == RECORD_FILE)


def checkpoint_config(path: Path) -> bool:
    """A checkpoint's config.json (a JSON object with its format version and model settings)."""
    return _json_object(path, ("format_version", "model"))


def _checkpoint_file(path: Path) -> bool:
    """One of a checkpoint's files, beside the checkpoint's config.json."""
    return path.name in CHECKPOINT_FILES and checkpoint_config(path.parent / "config.json")


MCAP = OutputKind("an MCAP file written by cnep", _cnep_mcap)
CHECKPOINT = OutputKind(
    f"a checkpoint folder written by `cnep train` (only {', '.join(CHECKPOINT_FILES)})", _checkpoint_file
)
RRD = OutputKind("a Rerun .rrd file", _rrd)
DECISIONS = OutputKind("a replay's decisions file", lambda p: _json_object(p, ("checkpoint", "recordings")))
WEIGHTS = OutputKind("a weights file written by torch.save", _torch_file)


def json_with(name: str, keys: Iterable[str]) -> OutputKind:
    """JSON files holding an object with `keys`."""
    keys = tuple(keys)
    return OutputKind(name, lambda p: _json_object(p, keys))


def markdown_titled(name: str, title: str) -> OutputKind:
    """Markdown files whose first line is `# <title>`."""

    def test(path: Path) -> bool:
        try:
            with open(path, encoding="utf-8") as f:
                return f.readline().rstrip("\n") == f"# {title}"
        except (OSError, ValueError):
            return False

    return OutputKind(name, test)


def png_by_matplotlib(path: Path) -> bool:
    """A PNG file that matplotlib wrote (it signs its files)."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return False
    return head.startswith(b"\x89PNG") and b"Matplotlib" in head


def foreign_files(root: Path, unrecorded: Callable[[Path], bool]) -> list[Path]:
    """What under the folder `root` (all depths) no cnep command recorded writing, sorted: files and links that the
    record of their folder does not name unchanged; in a folder without a record, those `unrecorded` rejects."""
    found = []
    for folder, dirs, files in os.walk(root):
        record = read_record(Path(folder))
        written = partial(is_recorded, record=record) if record is not None else unrecorded
        for name in [*files, *(d for d in dirs if os.path.islink(os.path.join(folder, d)))]:
            path = Path(folder) / name
            if path.is_symlink() or not (_bookkeeping(path) or written(path)):
                found.append(path)
    return sorted(found)


def not_written(path: Path, kind: OutputKind) -> list[Path]:
    """The files that make the existing output `path` not cnep's to replace (empty: `--force` may replace it).

    A folder: what in it cnep did not write (`kind.folder`, else `foreign_files`). A file: itself, unless its
    folder's record names it unchanged; in a folder without a record, itself unless it is of `kind`, and then
    the folder's other files not of `kind` (an unrecorded folder is cnep's only when it holds nothing else)."""
    path = Path(path)
    if path.is_symlink():
        return [path]
    if path.is_dir():
        return kind.folder(path) if kind.folder is not None else foreign_files(path, kind.test)
    record = read_record(path.parent)
    if record is not None:
        return [] if is_recorded(path, record) else [path]
    if not kind(path):
        return [path]
    return [
        p
        for p in sorted(path.parent.iterdir())
        if p.is_symlink() or (p.is_file() and not _bookkeeping(p) and not kind(p))
    ]
