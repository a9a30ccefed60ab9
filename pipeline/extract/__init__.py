"""Stage `extract`: demonstration MCAP files -> trajectory MCAP files of 1288-d steps [features | pose | gripper].

`stage` runs the MobileNet-v2 extractor of `perception` over each file's frames and writes the
trajectory file beside the extractor's identity, which train and replay check.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(__name__, {"stage": ("ExtractConfig", "extract")})
