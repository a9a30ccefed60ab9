"""The simulator's demonstrations as a user's robot would write them: per demonstration a folder of PNG frames and a
pose CSV (`t,x,y,z,qx,qy,qz,qw,gripper`, seconds and metres), which `cnep ingest` takes as it takes a user's
(docs/how-to/own-csv-and-video.md); `ingest_demonstrations` runs it.

The task's scripted demonstrator (Task.demonstrations) drives the environment itself: the frames and poses are what
the camera saw and the robot reported while it moved, not the plan.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2

from cnep.outputs import record_written, temporary_path, writer
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.pipeline.progress import progress_bar
from cnep.pipeline.sim.config import demonstrations_task
from cnep.recordings.csv_motion import CsvColumns
from cnep.runtime import STATE_NAMES
from cnep.sim import scene as S
from cnep.sim.task import Demonstration, Task

CSV_FILE = "poses.csv"
CSV_HEADER = ("t", *STATE_NAMES)
TIME_UNIT = "s"  # the CSV's time column, stated to the ingest (`cnep ingest --column time_unit=s`)


@dataclass(frozen=True)
class Generated:
    """folders: one per demonstration (sorted); behaviours: what each did (Task.behaviours); successes: how many
    succeeded (the task's verdict: reached the goal clear of the box; put the bar on a valid place)."""

    folders: list[Path]
    behaviours: list[str]
    successes: int


def generate_demonstrations(task: Task, out: Path, n: int, seed: int, quiet: bool = False, **variants) -> Generated:
    """Write `n` demonstrations of `task` (in its `variants`) into out/demo_NNN/ (frames + CSV), seeded by `seed`."""
    folders, behaviours, successes = [], [], 0
    made = progress_bar(task.demonstrations(n, seed, **variants), total=n, desc="generate", unit="demo", quiet=quiet)
    for i, demo in enumerate(made):
        folders.append(out / f"demo_{i:03d}")
        _write(folders[-1], demo)
        behaviours.append(demo.behaviour)
        successes += demo.clean
    return Generated(folders, behaviours, successes)


def ingest_demonstrations(recorded: Path, out: Path, task: Task, quiet: bool = False) -> None:
    """`cnep ingest` of the folders `generate_demonstrations` wrote into `recorded`, into `out`: the CSV's time unit
    stated (nothing to infer, nothing said per file), each demonstration's task `task` and its environments' version
    (demonstrations_task: what the trained policies record and `cnep sim eval` runs them on)."""
    columns = CsvColumns(time_unit=TIME_UNIT)
    label = demonstrations_task(task.name, task.version)
    ingest(IngestConfig(src=recorded, out=out, columns=columns, task=label, quiet=quiet))


def _write(folder: Path, demo: Demonstration) -> None:
    """One demonstration's frames and CSV, written under a temporary name and renamed when complete; where a command
    writes (cnep.outputs.writing_as), named in the folder's record as its outputs before the rename."""
    work = temporary_path(folder)
    work.mkdir(parents=True)
    rows = []
    for k, (frame, state) in enumerate(zip(demo.frames, demo.states)):
        _, png = cv2.imencode(".png", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        (work / f"frame_{k:03d}.png").write_bytes(png.tobytes())
        rows.append([f"{k * S.CONTROL_PERIOD_S:.3f}", *(f"{v:.4f}" for v in state)])
    lines = [",".join(CSV_HEADER), *(",".join(row) for row in rows)]
    (work / CSV_FILE).write_text("\n".join(lines) + "\n")
    if writer() is not None:
        record_written(sorted(work.iterdir()))
    work.rename(folder)
