"""Errors a user can fix: the CLI prints these as one line and exits 2 (no traceback).

Each package keeps its own error class (they never import each other); this module gathers them.
"""

from __future__ import annotations

from models.errors import ConfigError
from perception.errors import PerceptionError
from recordings.errors import RecordingError


class PipelineError(Exception):
    """A stage was given inputs that do not fit together (naming the files and the fix)."""


USER_ERRORS: tuple[type[Exception], ...] = (PipelineError, ConfigError, RecordingError, PerceptionError)
