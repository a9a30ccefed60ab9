"""The extract stage's inputs: demonstration files given as files or folders (stdlib only, no torch)."""

from __future__ import annotations

from pathlib import Path

from cnep.pipeline.errors import PipelineError

SUFFIX = ".mcap"


def demonstration_files(given: Path) -> list[Path]:
    """`given` if it is a file, else the `*.mcap` files under folder `given` (recursively, sorted); PipelineError if
    none."""
    if given.is_dir():
        found = sorted(p for p in given.rglob(f"*{SUFFIX}") if p.is_file())
        if not found:
            raise PipelineError(
                f"{given}: no {SUFFIX} files in this folder; give demonstration files made by `cnep ingest`"
            )
        return found
    if given.is_file():
        return [given]
    raise PipelineError(f"{given}: no such file or folder; give demonstration files made by `cnep ingest`")
