"""The input files of a stage: files as given, folders searched for MCAP files, refused when missing.

Cheap (the file system only), so the `cnep` command checks its inputs with these before it loads the
stage and torch, onnx or rerun with it: a missing path is refused at once, with the message the stage
itself would give.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from cnep.pipeline.errors import PipelineError

SUFFIX = ".mcap"
DEMONSTRATIONS = "demonstration files made by `cnep ingest`"
TRAJECTORIES = "trajectory files made by `cnep extract`"


def mcap_files(given: Path, kind: str) -> list[Path]:
    """`given` if it is a file, else the `*.mcap` files under folder `given` (recursively, sorted).

    kind: what the files are, for the error (DEMONSTRATIONS, TRAJECTORIES); PipelineError when `given` does
    not exist or is a folder without MCAP files.
    """
    given = Path(given)
    if given.is_dir():
        found = sorted(p for p in given.rglob(f"*{SUFFIX}") if p.is_file())
        if not found:
            raise PipelineError(f"{given}: no {SUFFIX} files in this folder; give {kind}")
        return found
    if given.is_file():
        return [given]
    raise PipelineError(f"{given}: no such file or folder; give {kind}")


def find_demonstration_files(inputs: Sequence[Path]) -> list[Path]:
    """Files as given, folders searched recursively for `*.mcap` (sorted), in the order given; PipelineError for a
    missing input or a folder without MCAP files."""
    return [path for given in inputs for path in mcap_files(Path(given), DEMONSTRATIONS)]


def existing_files(paths: Sequence[Path], kind: str) -> list[Path]:
    """`paths`, each an existing file; PipelineError naming the first that is not (kind: what they are)."""
    for path in map(Path, paths):
        if not path.is_file():
            problem = "is a folder" if path.is_dir() else "no such file"
            raise PipelineError(f"{path}: {problem}; give {kind}")
    return [Path(p) for p in paths]


def find_trajectory_files(inputs: Sequence[Path]) -> list[Path]:
    """Files as given, folders searched recursively for `*.mcap` (sorted), each file once; at least two (one is
    held out for validation). PipelineError for a missing input or too few files."""
    found = [path for given in inputs for path in mcap_files(given, TRAJECTORIES)]
    seen: set[Path] = set()
    unique = [p for p in found if not (p.resolve() in seen or seen.add(p.resolve()))]
    if len(unique) < 2:
        raise PipelineError(
            f"training needs at least 2 trajectory files (one is held out for validation), got "
            f"{len(unique)} from {', '.join(map(str, inputs))}"
        )
    return unique


def coerce_paths(config) -> None:
    """Give a stage's frozen config its path fields as `Path`s, as the `cnep` command does, where Python code passed
    strings (`TrainStageConfig(inputs=("trajectories",), out="model")`): fields annotated `Path`, `Path | None` and
    `tuple[Path, ...]` (a lone string there is one path). Call it first in the config's `__post_init__`."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.type in ("Path", "Path | None") and isinstance(value, str):
            object.__setattr__(config, f.name, Path(value))
        elif f.type == "tuple[Path, ...]":
            given = (value,) if isinstance(value, (str, Path)) else value
            object.__setattr__(config, f.name, tuple(Path(v) for v in given))


def read_json_object(path: Path, what: str, fix: str) -> dict:
    """The JSON object in the file at `path` (`what` it is, for the error), read within the bounds of any JSON a user
    hands cnep (runtime.jsonfile); PipelineError naming the file, the problem and `fix` where it cannot be read or
    holds no JSON object."""
    from cnep.runtime.jsonfile import read_json

    try:
        data = read_json(path)
    except (OSError, ValueError) as exc:
        raise PipelineError(f"{path}: cannot read {what} ({exc}); {fix}") from None
    if not isinstance(data, dict):
        raise PipelineError(f"{path}: {what} holds one JSON object, got {type(data).__name__}; {fix}")
    return data
