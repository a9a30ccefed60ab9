"""A checkpoint of the train stage, loaded for recordings: the model and the recording columns it takes.

    trained = load_trained(checkpoint_dir)
    rows = trained.rows(read_trajectory(path), path)  # (T, model width) float32, the model's columns
    trained.check_extractor({path: trajectory.extractor})  # features from the training data's extractor

Which recording columns the model sees: the checkpoint's `layout` entry, written by the train stage
(`TrainingColumns.to_dict`: `recording_width`, `columns` = spans of the recording handed to the model,
`blocks` = where each block lies in model columns); without it, the model's own columns over the whole
row, with the recording's blocks of that width. A recording of another width gives the model's blocks
found by name in its own blocks, or is refused.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.models import CNEP, load_checkpoint, read_checkpoint_config
from cnep.models.checkpoint import CONFIG_FILE
from cnep.models.config import in_message
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.identity import Identity, check_checkpoint_extractor
from cnep.pipeline.train.config import checkpoint_conditioning
from cnep.pipeline.train.constants import EXPERT_LABELS
from cnep.recordings import Trajectory
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_POSE_XYZ, BLOCKS_BY_WIDTH
from cnep.runtime.conditioning import ConditioningPolicy

Span = tuple[int, int]


@dataclass(frozen=True)
class RowMapping:
    """Recording columns -> model columns. `blocks`: block name -> (start, stop) in model columns."""

    recording_width: int
    columns: tuple[Span, ...]
    blocks: dict[str, Span]

    @classmethod
    def from_config(cls, config: dict, width: int, checkpoint: Path) -> RowMapping:
        """The mapping of a checkpoint's config.json (`config`) for a model `width` columns wide."""
        layout = config.get("layout")
        if isinstance(layout, dict) and "columns" in layout:
            mapping = cls(
                int(layout["recording_width"]),
                tuple((int(a), int(b)) for a, b in layout["columns"]),
                {k: (int(a), int(b)) for k, (a, b) in layout.get("blocks", {}).items()},
            )
        else:
            mapping = cls(width, ((0, width),), dict(BLOCKS_BY_WIDTH.get(width, {})))
        if sum(b - a for a, b in mapping.columns) != width:
            raise PipelineError(
                f"{checkpoint}: the layout's columns {mapping.columns} give "
                f"{sum(b - a for a, b in mapping.columns)} model columns but the model takes {width}; "
                f"the checkpoint is inconsistent, retrain it with `cnep train`"
            )
        return mapping

    def select(self, traj: Trajectory, path: Path, checkpoint: Path) -> np.ndarray:
        """(T, recording width) rows -> (T, model width) float32 rows.

        A recording of the training width gives the checkpoint's columns; one of another width gives the
        model's blocks found by name in its own blocks (a `motion` checkpoint takes the pose and gripper
        of 8- and 1288-column recordings alike); a recording without one of those blocks is refused.
        """
        if traj.width == self.recording_width:
            spans = self.columns
        else:
            missing = [name for name in self.blocks if name not in traj.blocks]
            if missing or not self.blocks:
                raise PipelineError(
                    f"{path}: the recording has {traj.width} columns per step "
                    f"({', '.join(traj.blocks)}) but the checkpoint {checkpoint} was trained on "
                    f"{self.recording_width}-column trajectories and needs "
                    f"{', '.join(missing or ['its training layout'])}; replay trajectory files made "
                    f"like its training data (check widths with `cnep inspect`)"
                )
            spans = tuple(traj.blocks[name] for name in sorted(self.blocks, key=lambda n: self.blocks[n][0]))
        return np.concatenate([traj.data[:, a:b] for a, b in spans], axis=1).astype(np.float32)

    @property
    def uses_features(self) -> bool:
        """True if the model sees the image features (so they must come from the checkpoint's extractor)."""
        return BLOCK_FEATURES in self.blocks

    def predicted_xyz(self, model: CNEP) -> list[int] | None:
        """Positions of the pose xyz columns among the model's predicted columns (None if not predicted)."""
        if BLOCK_POSE_XYZ not in self.blocks:
            return None
        out = model.out_columns.tolist()
        a, b = self.blocks[BLOCK_POSE_XYZ]
        return [out.index(c) for c in range(a, b)] if all(c in out for c in range(a, b)) else None


@dataclass(frozen=True)
class TrainedModel:
    """A loaded checkpoint: `path` (its folder), `model` (in eval mode), `mapping` (the recording columns it
    takes) and `config` (its config.json)."""

    path: Path
    model: CNEP
    mapping: RowMapping
    config: dict

    def rows(self, trajectory: Trajectory, path: Path) -> np.ndarray:
        """The (T, model width) float32 rows the model takes from `trajectory` (read from `path`)."""
        return self.mapping.select(trajectory, path, self.path)

    @property
    def expert_labels(self) -> dict[int, str]:
        """Expert -> the task of most of its training demonstrations, where they named tasks (`pipeline.train.experts`;
        {} otherwise); PipelineError naming the config file if its entry is not such a mapping."""
        labels = self.config.get(EXPERT_LABELS) or {}
        experts = {str(expert) for expert in range(self.model.n_experts)}
        if not isinstance(labels, dict) or not all(
            expert in experts and isinstance(label, str) for expert, label in labels.items()
        ):
            raise PipelineError(
                f"{self.path / CONFIG_FILE}: {EXPERT_LABELS} must map expert numbers (0 to {self.model.n_experts - 1}) "
                f"to task names, got {in_message(labels)}; retrain with `cnep train` instead of editing it"
            )
        return {int(expert): label for expert, label in labels.items()}

    @property
    def conditioning(self) -> ConditioningPolicy:
        """How a policy of the model conditions and picks its active expert, as trained (config.json's; a checkpoint
        written before it was stored: the defaults)."""
        return checkpoint_conditioning(self.config, self.path / CONFIG_FILE)

    def check_extractor(self, identities: Mapping[Path, Identity]) -> None:
        """Refuse recordings (path -> extractor identity) whose features come from another extractor than the
        training data's, when the model sees the features."""
        if self.mapping.uses_features:
            check_checkpoint_extractor(self.path / CONFIG_FILE, self.config.get("extractor") or {}, identities)


def load_trained(checkpoint: str | os.PathLike) -> TrainedModel:
    """The checkpoint folder written by `cnep train`, loaded with its column selection (on the CPU)."""
    path = Path(checkpoint)
    model = load_checkpoint(path)
    config = read_checkpoint_config(path)
    return TrainedModel(path, model, RowMapping.from_config(config, model.config.columns.width, path), config)
