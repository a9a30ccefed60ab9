"""Stage `ingest`: raw recordings (video/images + CSV, motion CSV, a robot's MCAP) -> demonstration MCAP files.

`stage` finds the sources and writes one demonstration file per source, atomically; the formats
themselves are read by `recordings`.
"""

from cnep.pipeline._lazy import stage_attribute


def __getattr__(name: str) -> object:
    return stage_attribute(__name__, name)
