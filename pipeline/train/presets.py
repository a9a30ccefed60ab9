"""The train stage's presets (`cnep train --layout`): which trajectory columns the model observes, queries, predicts.

A preset names blocks of the per-step vector (`recordings.constants`: features, pose_xyz,
pose_quat_xyzw, gripper). Resolved against a file width (1288 or 8) it gives the recording columns
handed to the model (`columns`, spans of the file, concatenated in order) and a `models.ColumnRoles` over
those model columns:

    preset       files   model width   observed (besides t)          query (besides t)   predicted
    wine-glass   1288    1288          features, pose, gripper        features            pose, gripper
    scene        1288    1288          features, pose, gripper        -                   pose, gripper
    motion       1288/8  8             pose, gripper                  -                   pose, gripper
    all          1288/8  1288/8        every column                   -                   every column

`scene` is `wine-glass` without the query features: a query is a time only, so what the camera
showed reaches the prediction through the context (the observed frames) and the gate alone; the
experts then have to split by what the scene asks for (the demo's behaviours).
`motion` always trains an 8-column model: on 1288-d files it takes their motion columns [1280, 1288)
and ignores the features, so its checkpoint fits motion-only and full recordings alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.models import ColumnRoles
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.constants import ALL, MOTION, SCENE, WINE_GLASS
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_GRIPPER, BLOCK_POSE_QUAT, BLOCK_POSE_XYZ, BLOCKS_BY_WIDTH

MOTION_BLOCKS = (BLOCK_POSE_XYZ, BLOCK_POSE_QUAT, BLOCK_GRIPPER)
EVERY_BLOCK = None  # stands for every block of the file, in file order


@dataclass(frozen=True)
class Preset:
    """Block names per role; `kept` are the blocks handed to the model (EVERY_BLOCK: the whole file)."""

    observed: tuple[str, ...] | None
    query: tuple[str, ...]
    predicted: tuple[str, ...] | None
    kept: tuple[str, ...] | None


PRESETS: Mapping[str, Preset] = {
    WINE_GLASS: Preset(
        observed=(BLOCK_FEATURES, *MOTION_BLOCKS), query=(BLOCK_FEATURES,), predicted=MOTION_BLOCKS, kept=EVERY_BLOCK
    ),
    SCENE: Preset(observed=(BLOCK_FEATURES, *MOTION_BLOCKS), query=(), predicted=MOTION_BLOCKS, kept=EVERY_BLOCK),
    MOTION: Preset(observed=MOTION_BLOCKS, query=(), predicted=MOTION_BLOCKS, kept=MOTION_BLOCKS),
    ALL: Preset(observed=EVERY_BLOCK, query=(), predicted=EVERY_BLOCK, kept=EVERY_BLOCK),
}


@dataclass(frozen=True)
class TrainingColumns:
    """A preset resolved for files of one width.

    columns: spans of the recording's columns given to the model, concatenated in order;
    blocks: block name -> (start, stop) in model columns; roles: what the model does with each of its columns
    (`models.ColumnRoles`).
    """

    name: str
    recording_width: int
    columns: tuple[tuple[int, int], ...]
    blocks: Mapping[str, tuple[int, int]]
    observed: tuple[str, ...]
    query: tuple[str, ...]
    predicted: tuple[str, ...]
    roles: ColumnRoles

    def select(self, data: np.ndarray) -> np.ndarray:
        """(T, recording_width) recording rows -> (T, model width) model rows."""
        return np.concatenate([data[:, a:b] for a, b in self.columns], axis=1)

    def to_dict(self) -> dict:
        """JSON-able description stored in the checkpoint's config.json (replay reads it to refuse misfits)."""
        return {
            "name": self.name,
            "recording_width": self.recording_width,
            "columns": [list(span) for span in self.columns],
            "blocks": {name: list(span) for name, span in self.blocks.items()},
            "observed": list(self.observed),
            "query": list(self.query),
            "predicted": list(self.predicted),
        }


def resolve_preset(name: str, width: int, example: Path) -> TrainingColumns:
    """Preset `name` for trajectory files `width` columns wide; `example` (one such file) names them in errors."""
    if name not in PRESETS:
        raise PipelineError(f"unknown layout {name!r}; choose one of {', '.join(PRESETS)}")
    preset, file_blocks = PRESETS[name], BLOCKS_BY_WIDTH[width]
    needed = {*(preset.observed or ()), *preset.query, *(preset.predicted or ()), *(preset.kept or ())}
    missing = sorted(needed - set(file_blocks))
    if missing:
        raise PipelineError(
            f"{example}: layout {name!r} needs the block(s) {', '.join(missing)} but these "
            f"trajectory files are {width} columns wide ({', '.join(file_blocks)}); use --layout "
            f"{MOTION} for motion-only files, or extract trajectories from demonstrations with frames"
        )
    kept = [b for b in file_blocks if preset.kept is EVERY_BLOCK or b in preset.kept]  # file order
    blocks, start = {}, 0
    for block in kept:
        a, b = file_blocks[block]
        blocks[block] = (start, start + b - a)
        start += b - a
    observed = tuple(kept if preset.observed is EVERY_BLOCK else preset.observed)
    predicted = tuple(kept if preset.predicted is EVERY_BLOCK else preset.predicted)
    roles = ColumnRoles(
        width=start,
        observed=_spans(blocks, observed),
        query=_spans(blocks, preset.query),
        predicted=_spans(blocks, predicted),
    )
    return TrainingColumns(
        name=name,
        recording_width=width,
        columns=_spans(file_blocks, kept),
        blocks=blocks,
        observed=observed,
        query=preset.query,
        predicted=predicted,
        roles=roles,
    )


def _spans(blocks: Mapping[str, tuple[int, int]], names: Sequence[str]) -> tuple[tuple[int, int], ...]:
    """The column spans of `names` in order, adjacent spans merged: ((0, 1280), (1280, 1288)) -> ((0, 1288),)."""
    merged: list[tuple[int, int]] = []
    for name in names:
        a, b = blocks[name]
        if merged and merged[-1][1] == a:
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return tuple(merged)
