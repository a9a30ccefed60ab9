"""Stage `to-lerobot`: demonstration MCAP files -> a LeRobot v3.0 dataset (recordings.lerobot_writer).

`config` holds its settings (no torch, no pyarrow); `stage` checks the demonstrations and writes the dataset.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(__name__, {"config": ("ToLerobotConfig",), "stage": ("to_lerobot",)})
