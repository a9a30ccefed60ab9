"""The export stage's settings (`ExportConfig`): what `cnep export` and `export()` take.

Importable without torch or onnx: the `cnep export` command builds its config (and so checks its options)
and checks its input paths before it loads the stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cnep.models.config import ConditioningOverrides
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.runtime.timebase import TimeBase


@dataclass(frozen=True)
class ExportConfig:
    """checkpoint: folder written by `cnep train` (read only); out: the policy folder (must not exist unless
    `force`); extractor: weights file of the training features (None: ImageNet); int8: add the int8 feature
    graph, calibrated on the frames of the demonstration files or folders `calibration`; time_base: the policy's
    seconds -> phase (None: the checkpoint's, from its training demonstrations); conditioning: the conditioning
    settings that replace the checkpoint's in the manifest (those given)."""

    checkpoint: Path
    out: Path
    extractor: Path | None = None
    int8: bool = False
    calibration: tuple[Path, ...] = ()
    time_base: TimeBase | None = None
    conditioning: ConditioningOverrides = field(default_factory=ConditioningOverrides)
    force: bool = False
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        if self.int8 and not self.calibration:
            raise PipelineError(
                "int8 features are quantised on frames of the recordings: give demonstration files or folders "
                "with --calibration (e.g. the training demonstrations)"
            )
        if self.calibration and not self.int8:
            raise PipelineError("--calibration calibrates the int8 feature graph: add --int8, or leave it out")
