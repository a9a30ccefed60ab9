"""Stage `demo`: nothing -> a Rerun recording: the whole pipeline on built-in synthetic tabletop demonstrations.

`stage` runs generate -> ingest -> extract -> train -> replay; `scene` draws the tabletop and decides
the behaviour; `generator` records the seeded demonstrations as robot MCAP files.
"""

from cnep.pipeline._lazy import stage_attribute


def __getattr__(name: str) -> object:
    return stage_attribute(__name__, name)
