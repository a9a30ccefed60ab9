"""Stage `ingest`: raw recordings (video/images + CSV, motion CSV, a robot's MCAP) -> demonstration MCAP files.

`stage` finds the sources and writes one demonstration file per source, atomically; the formats
themselves are read by `recordings`.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(__name__, {"stage": ("IngestConfig", "ingest")})
