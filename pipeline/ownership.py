"""What cnep may replace or delete: only files it wrote itself, recognised by their content, never by name alone.

`--force` in every command replaces an existing output only when it is of the kind the command writes
(`OutputKind`): an MCAP file whose header names cnep's recording layer, a checkpoint folder holding only a
checkpoint's files, a Rerun `.rrd`, a JSON or Markdown file with the keys or title cnep writes, a weights
file as `--save-weights` writes it. A user's own file at that path is refused with one line
(`pipeline.contract.refuse_existing`), and so is an output that is an input or contains one
(`pipeline.contract.refuse_inputs`).
"""

from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from cnep.outputs import TEMPORARY, is_lock_name

CHECKPOINT_FILES = ("config.json", "model.safetensors", "training_log.jsonl")
RRD_MAGIC = b"RRF"  # every Rerun .rrd starts with it (RRF2 in rerun 0.41)


@dataclass(frozen=True)
class OutputKind:
    """A kind of output: what it is called in messages, and a test of a path's content."""

    name: str
    test: Callable[[Path], bool]

    def __call__(self, path: Path) -> bool:
        return self.test(Path(path))


def _cnep_mcap(path: Path) -> bool:
    from cnep.recordings.constants import LIBRARY_NAME
    from cnep.recordings.container import mcap_library

    return path.is_file() and mcap_library(path) == LIBRARY_NAME


def _json_object(path: Path, keys: Iterable[str] = ()) -> bool:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
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
    """A temporary file or lock file of cnep's output layer."""
    return path.is_file() and (TEMPORARY.match(path.name) is not None or is_lock_name(path.name))


def checkpoint_config(path: Path) -> bool:
    """A checkpoint's config.json (a JSON object with its format version and model settings)."""
    return _json_object(path, ("format_version", "model"))


def _checkpoint_folder(path: Path) -> bool:
    """A folder holding a checkpoint's files only (an empty folder too: replacing it loses nothing)."""
    if not path.is_dir() or path.is_symlink():
        return False
    entries = list(path.iterdir())
    if entries and not checkpoint_config(path / "config.json"):
        return False
    return all(entry.name in CHECKPOINT_FILES or _bookkeeping(entry) for entry in entries)


MCAP = OutputKind("an MCAP file written by cnep", _cnep_mcap)
CHECKPOINT = OutputKind(
    f"a checkpoint folder written by `cnep train` (holding only {', '.join(CHECKPOINT_FILES)})", _checkpoint_folder
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


def cnep_file(path: Path) -> bool:
    """True for any file one of cnep's commands writes (by content, per suffix), and cnep's temporaries and locks."""
    path = Path(path)
    if _bookkeeping(path):
        return True
    if path.suffix == ".mcap":
        return _cnep_mcap(path)
    if path.suffix == ".rrd":
        return _rrd(path)
    if path.suffix in (".json", ".jsonl"):
        return path.is_file() and (path.suffix == ".jsonl" or _json_object(path))
    if path.suffix in (".pt", ".safetensors"):
        return path.is_file()
    if path.suffix == ".png":  # the demo's and the evaluation's figures: matplotlib signs its PNG files
        return _png_by_matplotlib(path)
    return False


def _png_by_matplotlib(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return False
    return head.startswith(b"\x89PNG") and b"Matplotlib" in head


def foreign_files(folder: Path) -> list[Path]:
    """Files (and links) under `folder` that cnep did not write (`cnep_file`), sorted."""
    found = []
    for root, dirs, files in os.walk(folder):
        for name in [*files, *(d for d in dirs if os.path.islink(os.path.join(root, d)))]:
            path = Path(root) / name
            if path.is_symlink() or not cnep_file(path):
                found.append(path)
    return sorted(found)
