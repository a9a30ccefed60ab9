"""What a command may replace or delete: only what the same command recorded writing, checked again when it does.

Every stage says which command it is (`cnep.outputs.writing_as`: the stages the demo and `cnep sim` run for
themselves write as the demo and the simulator) and names its outputs in the record of their folder
(`cnep.outputs.record`: each file with its size, sha256 and command). An existing output is replaced (`--force`)
only when its folder's record names it as written by the same command, unchanged; a folder replaced as a whole (a
checkpoint, the demo's folder) only when every file in it, at every depth, is so named. A folder without a record
is the user's, and so is a file another command wrote. An exported policy folder is the one exception: its
manifest, which names every file with its sha256, is its record (`pipeline.export.stage`).

A command checks this before it starts (`pipeline.contract.refuse_existing`, with one line naming the first file
that is not its own) and again at the moment it replaces (`cnep.outputs.staged(record=True)` for files,
`cnep.outputs.publish_folder` for folders); it never writes inside its input (`pipeline.contract.refuse_inputs`).
"""

from __future__ import annotations

from pathlib import Path

from cnep.outputs import Owns, foreign_files


def not_written(path: Path, owns: Owns) -> list[Path]:
    """The files that make the existing output `path` not the command's to replace (empty: it may replace it): a
    folder's files it does not own (`owns`), at every depth; a file or link, itself unless it owns it."""
    path = Path(path)
    if path.is_symlink():
        return [path]
    if path.is_dir():
        return foreign_files(path, owns)
    return [] if owns(path.parent, path) else [path]
