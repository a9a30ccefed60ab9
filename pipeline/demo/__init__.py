"""Stage `demo`: nothing -> a Rerun recording: the whole pipeline on built-in synthetic tabletop demonstrations.

`stage` runs generate -> ingest -> extract -> train -> replay -> summary; `scene` draws the tabletop and
decides the behaviour; `generator` records the seeded demonstrations as robot MCAP files; `weights` chooses the
feature network's weights; `measures` and `free_choice` measure what the summary reports; `report` prints it.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__, {"config": ("DemoConfig",), "stage": ("run_demo",), "report": ("format_summary",)}
)
