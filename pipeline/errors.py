"""Errors a user can fix: the CLI prints these as one line and exits 2 (no traceback).

Each package keeps its own error class (they never import each other); this module gathers them.
Importing it costs nothing: the other packages' classes are looked up only when asked for, so
`cnep inspect` (recordings only) never pulls in torch through here.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence
from pathlib import Path

# (module, class) of every package's user-error class besides PipelineError.
_PACKAGE_ERRORS = (
    ("cnep.models.errors", "ConfigError"),
    ("cnep.recordings.errors", "RecordingError"),
    ("cnep.perception.errors", "PerceptionError"),
    ("cnep.outputs.errors", "OutputError"),
    ("cnep.runtime.errors", "PolicyError"),
    ("cnep.sim.errors", "SimError"),
)


class PipelineError(Exception):
    """A stage was given inputs that do not fit together (naming the files and the fix)."""


def loaded_user_errors() -> tuple[type[Exception], ...]:
    """PipelineError and the error classes of the packages imported so far.

    An error of a package that was never imported cannot have been raised, so catching these is the
    same as catching USER_ERRORS, without importing torch (models, perception) to do it.
    """
    found = [getattr(sys.modules[name], cls) for name, cls in _PACKAGE_ERRORS if name in sys.modules]
    return (PipelineError, *found)


def listed(files: Sequence[Path | str], shown: int = 5) -> str:
    """The first `shown` of `files` for an error message, comma-separated, then how many more there are."""
    names = ", ".join(str(f) for f in files[:shown])
    return names + (f" and {len(files) - shown} more" if len(files) > shown else "")


def __getattr__(name: str):
    if name == "USER_ERRORS":  # every package's class, importing them (and torch) now
        classes = tuple(getattr(importlib.import_module(module), cls) for module, cls in _PACKAGE_ERRORS)
        return (PipelineError, *classes)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
