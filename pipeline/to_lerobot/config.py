"""The settings of `cnep to-lerobot` (`ToLerobotConfig`): demonstrations -> a LeRobot v3.0 dataset.

Importable without pyarrow or PyAV: the command builds its config (and so checks its options) and checks its
input paths before it loads the stage.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from cnep.models.config import setting
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.recordings.constants import CAMERA_NAME
from cnep.recordings.csv_motion import PLAUSIBLE_RATE_HZ
from cnep.recordings.lerobot_video import VideoSettings
from cnep.runtime.constants import IMAGE_KEY_PREFIX

NAME_MAX = 255  # the longest file or folder name (bytes) of the common file systems


@dataclass(frozen=True)
class ToLerobotConfig:
    """demos: demonstration files or folders (read only), one episode each in the order found; out: the dataset folder
    (must not exist unless `force`, which replaces only a dataset cnep wrote); camera: the frames' feature name
    (`observation.images.CAMERA`; "" writes motion only); fps: the dataset's rate (None: the demonstrations' own);
    video: how the frames are encoded."""

    demos: tuple[Path, ...]
    out: Path
    camera: str = setting(CAMERA_NAME, 'the camera feature: observation.images.CAMERA ("" writes motion only)')
    fps: float | None = setting(None, "the dataset's rate in Hz, LeRobot's one per dataset")
    video: VideoSettings = field(default_factory=VideoSettings)
    force: bool = False
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        if not self.demos:
            raise PipelineError("to-lerobot needs at least one demonstration file or folder")
        low, high = PLAUSIBLE_RATE_HZ
        if self.fps is not None and not low <= self.fps <= high:
            raise PipelineError(f"--fps {self.fps:g}: the dataset's rate must be from {low:g} to {high:g} Hz")
        if "/" in self.camera or "\0" in self.camera:
            raise PipelineError(f"--camera {self.camera[:80]!r}: a LeRobot feature name has no '/' or NUL")
        if len(os.fsencode(IMAGE_KEY_PREFIX + self.camera)) > NAME_MAX:
            raise PipelineError(
                f"--camera: the feature {IMAGE_KEY_PREFIX}CAMERA names a folder of the dataset, at most {NAME_MAX} "
                f"bytes, and this one has {len(os.fsencode(IMAGE_KEY_PREFIX + self.camera))}"
            )

    @property
    def camera_key(self) -> str | None:
        """The video feature's key, None for motion only."""
        return IMAGE_KEY_PREFIX + self.camera if self.camera else None
