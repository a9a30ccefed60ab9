"""A unit of `cnep sim grid`'s work, self-contained so that a local worker process or a Dask / Ray worker runs it
(pipeline.evaluate.executors): one task's demonstration subset (the first `d` demonstrations of each behaviour in a
set) and one training seed, its cells the models evaluated on it.

    results = run_grid_unit(unit, bar)  # model -> protocol -> rates (or -> condition -> rates), as `cnep sim` has

It composes `cnep sim TASK`'s stages (pipeline.sim.stage) in the unit's folder, RUN: the trajectories of the subset
(linked from the subset's folder, as is the extractor they were extracted with), then train (`training_jobs`: the
CNEP and the matched CNMP of the seed, one after the other in this process, each keeping its candidate checkpoints),
the choice of each model's kept checkpoint on the validation episodes (pipeline.sim.selection, in this process),
export and the closed loop (`evaluate_one`: each model, and each baseline fitted beside the CNEP). A checkpoint or a
policy folder already in RUN is complete (each stage renames its work folder into place when done) and is used as it
is (a checkpoint still holding its candidates is chosen from first), so a unit interrupted after training resumes at
the choice or the export.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from cnep.outputs import temporary_path
from cnep.pipeline.demo.stage import train_one_after_another
from cnep.pipeline.progress import RemoteBar
from cnep.pipeline.sim.config import MODELS, PickPlaceConfig, SimConfig
from cnep.pipeline.sim.selection import select_checkpoints
from cnep.pipeline.sim.stage import EXTRACTOR_FILE, evaluate_one, export_policies, training_jobs
from cnep.pipeline.train.constants import CANDIDATES_DIR
from cnep.sim.tasks import find_task


@dataclass(frozen=True)
class Unit:
    """name: the unit's name (`TASK-setS-dD-seedN`); task: the task's name; per_behaviour: D, the demonstrations per
    behaviour it asked for; demonstrations: how many it trains on (fewer than D of a behaviour the set holds fewer
    of); run: the unit's folder (RUN); config: the task's `cnep sim` settings its models train and run with (out =
    RUN, the set's seed, the one training seed, the grid's episodes, their seeds and protocol); models: the cells to
    make, MODELS and baselines' names."""

    name: str
    task: str
    per_behaviour: int
    demonstrations: int
    run: Path
    config: SimConfig | PickPlaceConfig
    models: tuple[str, ...]

    @property
    def seed(self) -> int:
        """The unit's training seed."""
        return self.config.train_seeds[0]

    def label(self, model: str) -> str:
        """The label `MODEL-seedN` under which `cnep sim TASK` names the model's checkpoint, policy and results."""
        return f"{model}-seed{self.seed}"


def link_subset(run: Path, subset_folder: Path, trajectories: list[Path]) -> None:
    """RUN/trajectories holding `trajectories` (files of `subset_folder`/trajectories) and RUN/extractor.pt the
    subset's, as hard links (copies where the file system has none); made under a temporary name and renamed, so RUN
    is complete or absent. Nothing to do where RUN exists."""
    if run.is_dir():
        return
    work = temporary_path(run)
    (work / "trajectories").mkdir(parents=True)
    pairs = [(path, work / "trajectories" / path.name) for path in trajectories]
    for source, target in [*pairs, (subset_folder / EXTRACTOR_FILE, work / EXTRACTOR_FILE)]:
        link_or_copy(source, target)
    work.rename(run)


def link_or_copy(source: Path, target: Path) -> None:
    """`target` a hard link to `source`, or a copy where the file system has no links."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def run_grid_unit(unit: Unit, bar: RemoteBar) -> dict[str, dict]:
    """The unit's cells (module docstring): model -> its results (pipeline.sim.loop.evaluate_policy's). bar: where
    the episodes done go, each cell's under its part MODEL (pipeline.evaluate.pool)."""
    run = unit.run
    models = set(unit.models)
    wanted = (models & {"CNMP"}) | ({"CNEP"} if models - {"CNMP"} else set())  # a baseline is fitted beside the CNEP
    jobs = {label: job for label, job in training_jobs(unit.config, run).items() if label.split("-seed")[0] in wanted}
    train_one_after_another(
        {label: job for label, job in jobs.items() if not Path(job.out).is_dir()},
        quiet=True,
        started=time.perf_counter(),
    )
    checkpoints = {label: Path(job.out) for label, job in jobs.items()}
    unselected = {label: c for label, c in checkpoints.items() if (c / CANDIDATES_DIR).is_dir()}  # trained, not chosen
    if unselected:
        select_checkpoints(
            unit.config, find_task(unit.task, unit.config.env_version), run, unselected, run / EXTRACTOR_FILE, workers=0
        )
    export_policies({label: c for label, c in checkpoints.items() if not (run / "policies" / c.name).is_dir()}, run)
    policies = {label: run / "policies" / checkpoint.name for label, checkpoint in checkpoints.items()}
    results = {}
    for model in unit.models:
        if model in MODELS:
            path, baseline = policies[unit.label(model)], None
        else:
            path, baseline = policies[unit.label("CNEP")], (model, unit.seed)
        results[model] = evaluate_one(
            unit.config, unit.task, run, unit.label(model), path, baseline, bar.part(model), None
        )
    return results
