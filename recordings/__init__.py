"""The recording layer: MCAP demonstration and trajectory files (numpy only, never torch).

Public API (stable; see docs/reference/mcap-schema.md for the file contract):

    records      Episode, Demonstration, Trajectory, Event
    writing      DemonstrationWriter, TrajectoryWriter, write_demonstration, write_trajectory
    reading      DemonstrationReader, TrajectoryReader, read_demonstration, read_trajectory
    events       add_events, read_events
    errors       RecordingError
    constants    recordings.constants (topics, schemas, BLOCKS_FULL, BLOCKS_MOTION, FORMAT_VERSION, ...)
"""

from cnep.recordings import constants
from cnep.recordings.constants import (
    BLOCKS_FULL,
    BLOCKS_MOTION,
    FEATURE_DIM,
    FORMAT_VERSION,
    MOTION_DIM,
    STEP_DIM,
)
from cnep.recordings.errors import RecordingError
from cnep.recordings.events import add_events, read_events
from cnep.recordings.readers import DemonstrationReader, TrajectoryReader, read_demonstration, read_trajectory
from cnep.recordings.records import Demonstration, Episode, Event, Trajectory
from cnep.recordings.summary import FileSummary, read_summary
from cnep.recordings.writers import DemonstrationWriter, TrajectoryWriter, write_demonstration, write_trajectory

__all__ = [
    "BLOCKS_FULL",
    "BLOCKS_MOTION",
    "FEATURE_DIM",
    "FORMAT_VERSION",
    "MOTION_DIM",
    "STEP_DIM",
    "Demonstration",
    "DemonstrationReader",
    "DemonstrationWriter",
    "Episode",
    "Event",
    "FileSummary",
    "RecordingError",
    "Trajectory",
    "TrajectoryReader",
    "TrajectoryWriter",
    "add_events",
    "constants",
    "read_demonstration",
    "read_events",
    "read_summary",
    "read_trajectory",
    "write_demonstration",
    "write_trajectory",
]
