"""`cnep sim grid`: the closed-loop benchmark, every cell task x demonstration set x training seed x demonstrations per
behaviour x model evaluated on the same reported episode seeds (pipeline.sim.grid_config.GridConfig), resumable.

Under OUT:

    grid.json        the settings every cell shares (a rerun with others is refused)
    sets/TASK-setS/  a demonstration set, made once for every cell that uses it: `cnep sim TASK`'s generate and
                     ingest (pipeline.sim.stage), the largest number of demonstrations per behaviour of each
                     behaviour; set.json, what each demonstration did
    sets/TASK-setS-dD/  the set's first D demonstrations of each behaviour, extracted as `cnep extract` extracts
                     that many recordings of a user's (the extractor calibrated on them, their views by its rule),
                     once for every training seed
    runs/TASK-setS-dD-seedN/   a unit (pipeline.sim.grid_unit): that subset's trajectories, the CNEP and the CNMP of
                     training seed N trained, exported and run in closed loop
    cells/TASK-setS-dD-seedN-MODEL.json   a finished cell: its rates on the reported episodes
    grid.csv, grid.md   every cell's rows, and the table pooled over sets and seeds (pipeline.sim.grid_table)

Each file is written whole or not at all (cnep.outputs) and named in the folder's record as `sim grid`'s: a rerun
skips every set and cell whose file exists, so an interrupted grid resumes where it stopped, and a grid with more
sets or seeds adds only their cells. The units run `workers` at a time in single-threaded processes here, or on a
Dask or Ray cluster (pipeline.evaluate.executors; its workers reach OUT on a shared file system); one bar counts
their episodes.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

from cnep.outputs import output_lock, write_output, writing_as
from cnep.pipeline.contract import output_folder
from cnep.pipeline.demo.stage import quiet_per_file_logs
from cnep.pipeline.demo.weights import choose_weights
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.executors import check_cluster
from cnep.pipeline.evaluate.pool import as_finished
from cnep.pipeline.folders import assembled_folder
from cnep.pipeline.inputs import read_json_object
from cnep.pipeline.sim.baselines import COMPARED
from cnep.pipeline.sim.config import MODELS, PICK_PLACE, PickPlaceConfig, SimConfig
from cnep.pipeline.sim.extras import require_extras
from cnep.pipeline.sim.generate import generate_demonstrations, ingest_demonstrations
from cnep.pipeline.sim.grid_config import GridConfig, subset
from cnep.pipeline.sim.grid_table import cell_rows, csv_text, pooled_table
from cnep.pipeline.sim.grid_unit import Unit, link_or_copy, link_subset, run_grid_unit
from cnep.pipeline.sim.loop import episodes_of, for_task
from cnep.pipeline.sim.stage import extract_features
from cnep.sim.task import Task
from cnep.sim.tasks import find_task

log = logging.getLogger(__name__)

GRID_FILE, SET_FILE, CSV_FILE, TABLE_FILE = "grid.json", "set.json", "grid.csv", "grid.md"


@dataclass(frozen=True)
class GridResult:
    """cells: how many the grid has; ran: how many this run made; rows: the CSV's; table: the pooled Markdown table."""

    cells: int
    ran: int
    rows: list[dict]
    table: str


def run_grid(config: GridConfig) -> GridResult:
    """Every cell of `config` that OUT does not hold yet, then OUT's CSV and table of all of `config`'s cells (module
    docstring)."""
    require_extras(config, "cnep sim grid")
    check_cluster(config.executor, config.address)  # before any set is made, not once they are
    out = Path(config.out)
    with writing_as("sim grid"), output_folder(out), output_lock(out, folder=True):
        check_grid_folder(out, config)
        units = plan(config, out)
        cells = len(config.tasks) * len(config.sets) * len(config.per_behaviour) * len(config.train_seeds)
        cells *= len(models_of(config))
        ran = sum(len(unit.models) for unit in units.values())
        log.info("%d cells, %d of them done before; %d units to run", cells, cells - ran, len(units))
        (out / "cells").mkdir(exist_ok=True)
        for unit, results in run_units(list(units.values()), config):
            for model, result in results.items():
                write_output(
                    out / "cells" / f"{unit.name}-{model}.json", json.dumps(cell(unit, model, result)).encode()
                )
        rows = [row for path in cell_files(config, out) for row in rows_of_cell(path)]
        table = pooled_table(rows)
        write_output(out / CSV_FILE, csv_text(rows).encode())
        write_output(out / TABLE_FILE, (table + "\n").encode())
    return GridResult(cells, ran, rows, table)


def check_grid_folder(out: Path, config: GridConfig) -> None:
    """Write OUT/grid.json into a new or empty OUT; in a grid's folder, PipelineError unless its settings are
    `config`'s (GridConfig.shared); in another folder, PipelineError."""
    shared, grid_file = config.shared(), out / GRID_FILE
    if grid_file.is_file():
        before = read_grid_file(grid_file, "give another --out for a new grid")
        differ = [name for name in shared if before.get(name) != json.loads(json.dumps(shared[name]))]
        if differ:
            given = ", ".join(f"--{n.replace('_', '-')} {before.get(n)}" for n in differ)
            raise PipelineError(
                f"{grid_file}: this grid ran with {given}; give the same to resume it, or another --out for a new grid"
            )
        return
    if any(p for p in out.iterdir() if not p.name.startswith(".")):
        raise PipelineError(f"{out}: `cnep sim grid --out` takes a new or empty folder, or a grid's (with {GRID_FILE})")
    write_output(grid_file, json.dumps(shared, indent=1).encode())


def models_of(config: GridConfig) -> tuple[str, ...]:
    """The models of each unit: the CNEP and the CNMP, and the baselines where asked for."""
    return (*MODELS, *COMPARED) if config.baselines else MODELS


def plan(config: GridConfig, out: Path) -> dict[str, Unit]:
    """The units of the grid with a missing cell, by name, their `models` those cells; the sets they need made first
    and their folders linked."""
    units = {}
    for task_name in config.tasks:
        task = find_task(task_name, config.env_version)
        for set_seed in config.sets:
            set_folder = out / "sets" / f"{task.name}-set{set_seed}"
            behaviours = None
            for d in config.per_behaviour:
                for seed in config.train_seeds:
                    name = f"{task.name}-set{set_seed}-d{d}-seed{seed}"
                    missing = tuple(m for m in models_of(config) if not (out / "cells" / f"{name}-{m}.json").is_file())
                    if not missing:
                        continue
                    if behaviours is None:
                        behaviours = make_set(config, task, set_seed, set_folder)
                    chosen = subset(behaviours, task.behaviours, d)
                    subset_folder = make_subset(config, task, set_folder, set_seed, d, chosen)
                    trajectories = [trajectory_of(subset_folder, i) for i in chosen]
                    run = out / "runs" / name
                    link_subset(run, subset_folder, trajectories)
                    settings = task_config(config, task, run, set_seed, seed, len(chosen))
                    units[name] = Unit(name, task.name, d, len(chosen), run, settings, missing)
    return units


def task_config(
    config: GridConfig, task: Task, run: Path, set_seed: int, seed: int, demonstrations: int
) -> SimConfig | PickPlaceConfig:
    """The task's `cnep sim` settings for a unit: its defaults but for the grid's (the training steps where given, the
    feature components, the episodes, their seeds, the protocol, no recordings) and the unit's (its folder, set,
    seed)."""
    cls = PickPlaceConfig if task.name == PICK_PLACE else SimConfig
    given = {"train_steps": config.train_steps} if config.train_steps is not None else {}
    settings = cls(
        out=run, demonstrations=max(2, demonstrations), seed=set_seed, train_seeds=(seed,), episodes=config.episodes,
        episode_seed=config.episode_seed, max_steps=config.max_steps, protocol=config.protocol, record=0,
        env_version=config.env_version, feature_components=config.feature_components,
        baselines=config.baselines, weights=config.weights, offline=config.offline, quiet=True, **given,
    )  # fmt: skip
    return for_task(settings, task)


def make_set(config: GridConfig, task: Task, set_seed: int, folder: Path) -> list[str]:
    """The demonstration set `folder` (made now where it is missing: generate, ingest, SET_FILE: each demonstration's
    behaviour, the clean ones, the weights its subsets are extracted with); returns what each of its demonstrations
    did (Task.behaviours' names), in order."""
    if (folder / "trajectories").is_dir():
        raise PipelineError(
            f"{folder}: this set holds the features of all its demonstrations extracted at once, where the grid's "
            f"cells train on each subset extracted on its own; give another --out for a new grid"
        )
    if not folder.is_dir():
        weights = choose_weights(config.weights, config.offline).weights  # before anything is made
        n = max(config.per_behaviour) * len(task.behaviours)
        log.info("demonstration set %s: %d demonstrations", folder.name, n)
        with quiet_per_file_logs(), assembled_folder(folder, lambda: None) as work:
            made = generate_demonstrations(task, work / "recorded", n, set_seed, config.quiet)
            ingest_demonstrations(work / "recorded", work / "demos", task, config.quiet)
            made_set = {"behaviours": made.behaviours, "clean": made.successes, "weights": weights}
            write_output(work / SET_FILE, json.dumps(made_set).encode())
    behaviours = set_record(folder).get("behaviours")
    if not (isinstance(behaviours, list) and all(isinstance(b, str) for b in behaviours)):
        raise PipelineError(
            f"{folder / SET_FILE}: its behaviours are not a list of names; delete {folder} to make the set again"
        )
    return behaviours


def make_subset(config: GridConfig, task: Task, set_folder: Path, set_seed: int, d: int, chosen: list[int]) -> Path:
    """The folder `set_folder`-dD holding the set's demonstrations `chosen` (its first `d` of each behaviour) and their
    features, made now where it is missing: extracted with the set's weights and seed as `cnep extract` extracts as
    many recordings (the random weights calibrated on these, the views the rule gives their number), the weights saved
    beside them. A user who records that many demonstrations trains on what this holds."""
    folder = set_folder.with_name(f"{set_folder.name}-d{d}")
    if not folder.is_dir():
        weights = set_record(set_folder).get("weights")
        if not isinstance(weights, str):
            fix = f"delete {set_folder} to make the set again"
            raise PipelineError(f"{set_folder / SET_FILE}: it names no feature weights; {fix}")
        log.info("subset %s: extracting its %d demonstrations", folder.name, len(chosen))
        settings = task_config(config, task, folder, set_seed, config.train_seeds[0], len(chosen))
        with quiet_per_file_logs(), assembled_folder(folder, lambda: None) as work:
            (work / "demos").mkdir()
            for i in chosen:
                source = demonstration_of(set_folder, i)
                link_or_copy(source, work / "demos" / source.name)
            extract_features(replace(settings, out=work), work, weights)
    return folder


def set_record(folder: Path) -> dict:
    """The set's SET_FILE, read (read_grid_file)."""
    return read_grid_file(folder / SET_FILE, f"delete {folder} to make the set again")


def read_grid_file(path: Path, fix: str) -> dict:
    """The JSON object the grid wrote at `path` (grid.json, a set's set.json, a cell's file), read within the bounds of
    any JSON a user hands cnep (runtime.jsonfile); PipelineError naming the file and `fix` otherwise."""
    return read_json_object(path, "this file of the grid's", fix)


def rows_of_cell(path: Path) -> list[dict]:
    """The CSV rows of the cell file at `path` (grid_table.cell_rows); PipelineError naming it if it holds no cell."""
    fix = "delete it to run its cell again"
    cell = read_grid_file(path, fix)
    try:
        return cell_rows(cell)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise PipelineError(f"{path}: not a cell of the grid's ({type(exc).__name__}: {exc}); {fix}") from None


def trajectory_of(folder: Path, i: int) -> Path:
    """The trajectory file of demonstration `i` of a set in a subset's `folder` (generate's `demo_NNN`, ingested and
    extracted)."""
    return only_file(folder / "trajectories", i)


def demonstration_of(set_folder: Path, i: int) -> Path:
    """The ingested demonstration `i` of a set (generate's folder `demo_NNN`)."""
    return only_file(set_folder / "demos", i)


def only_file(folder: Path, i: int) -> Path:
    """The one MCAP file of demonstration `i` (`demo_NNN`) in `folder`; PipelineError unless there is exactly one."""
    found = sorted(folder.glob(f"demo_{i:03d}*.mcap"))
    if len(found) != 1:
        raise PipelineError(f"{folder}: expected one file of demo_{i:03d}, found {len(found)}")
    return found[0]


def run_units(units: list[Unit], config: GridConfig) -> Iterator[tuple[Unit, dict[str, dict]]]:
    """Yield (unit, its results) as the units finish, `config.workers` at a time here (0: in this process, one after
    another) or on the cluster `config.executor` names, one bar counting the episodes of their cells
    (pipeline.evaluate.pool)."""
    if not units:
        return
    by_name = {unit.name: unit for unit in units}
    calls = {unit.name: partial(run_grid_unit, unit) for unit in units}
    total = sum(episodes_of(find_task(u.task, u.config.env_version), u.config) * len(u.models) for u in units)
    finished = as_finished(
        calls, total, "grid", config.workers, config.quiet, config.executor, config.address, unit="episode"
    )
    for name, results in finished:
        yield by_name[name], results


def cell(unit: Unit, model: str, results: dict) -> dict:
    """A cell file's contents: the cell (grid_table.CELL) and its results."""
    return {
        "task": unit.task,
        "set": unit.config.seed,
        "per_behaviour": unit.per_behaviour,
        "demonstrations": unit.demonstrations,
        "model": model,
        "train_seed": unit.seed,
        "results": results,
    }


def cell_files(config: GridConfig, out: Path) -> list[Path]:
    """The files of `config`'s cells, in the grid's order: task, set, demonstrations per behaviour, seed, model."""
    names = [
        f"{task}-set{s}-d{d}-seed{seed}-{model}.json"
        for task in config.tasks
        for s in config.sets
        for d in config.per_behaviour
        for seed in config.train_seeds
        for model in models_of(config)
    ]
    return [out / "cells" / name for name in names]
