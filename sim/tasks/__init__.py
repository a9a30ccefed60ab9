"""The simulator's tasks, one folder each (its scene, environment, scripted demonstrator, scoring and drawing, its
environment's versions, and `task(version)`: its sim.task.Task on that version), named by the folder (`pick_place`:
"pick-place"): TASK_NAMES, and `find_task(name, version)`."""

from __future__ import annotations

import importlib
import pkgutil
from typing import TYPE_CHECKING

from cnep.sim.errors import SimError

if TYPE_CHECKING:
    from cnep.sim.task import Task

TASK_NAMES = tuple(sorted(m.name.replace("_", "-") for m in pkgutil.iter_modules(__path__) if m.ispkg))


def find_task(name: str, version: int) -> Task:
    """The task `name` (a TASK_NAMES entry) on its environment's `version`; its folder is imported now."""
    if name not in TASK_NAMES:
        raise SimError(f"there is no task {name!r}; the tasks are {', '.join(TASK_NAMES)}")
    try:
        return importlib.import_module(f"{__name__}.{name.replace('-', '_')}").task(version)
    except ValueError as error:
        raise SimError(str(error)) from None
