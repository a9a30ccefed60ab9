"""The recording layer: MCAP demonstration and trajectory files (numpy only, never torch).

Public API (stable; see docs/reference/mcap-schema.md for the file contract):

    records      Episode, Demonstration, Trajectory, Event
    writing      DemonstrationWriter, TrajectoryWriter, write_demonstration, write_trajectory
    reading      DemonstrationReader, TrajectoryReader, read_demonstration, read_trajectory
    events       add_events, read_events
    errors       RecordingError
    constants    recordings.constants (topics, schemas, BLOCKS_FULL, BLOCKS_MOTION, FORMAT_VERSION, ...)
"""

import importlib

# Module -> the public names it defines. A name's module is imported when the name is first used (PEP 562), so a
# light module (`cnep.recordings.constants`, the LeRobot layout and video settings the `cnep` command's options read)
# loads without the MCAP library.
_MODULES = {
    "constants": ("BLOCKS_FULL", "BLOCKS_MOTION", "FEATURE_DIM", "FORMAT_VERSION", "MOTION_DIM", "STEP_DIM"),
    "errors": ("RecordingError",),
    "events": ("add_events", "read_events"),
    "readers": ("DemonstrationReader", "TrajectoryReader", "read_demonstration", "read_trajectory"),
    "records": ("Demonstration", "Episode", "Event", "Trajectory"),
    "summary": ("FileSummary", "read_summary"),
    "writers": ("DemonstrationWriter", "TrajectoryWriter", "write_demonstration", "write_trajectory"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted([*_WHERE, "constants"])


def __getattr__(name: str) -> object:
    if name == "constants":
        return importlib.import_module(f"{__name__}.constants")
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
