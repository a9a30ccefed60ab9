"""`cnep sim grid`: its options become GridConfig and bad ones are refused in one line (the reported episode seeds
never the validation seeds); a set's subset takes the first demonstrations of each behaviour; a set holding the
features of all its demonstrations is refused; the CSV and the pooled table from cells' rates; and a tiny grid end to
end, its subset extracted on its own (1 task, 1 set, 1 seed, 2 demonstrations per behaviour, a few
training steps, 1 episode of a few steps, each model's checkpoint chosen from 2 candidates on one validation episode
per condition), run again with no work, and a lost cell made again from the unit's kept checkpoints."""

import importlib.util
import json
import re
from dataclasses import replace
from pathlib import Path

import pytest

import cnep.sim
from cnep.models.errors import ConfigError
from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.cli.sim import config_of
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.extract.stage import views_for
from cnep.pipeline.sim.config import SIM_TASKS, policy_task, task_and_version
from cnep.pipeline.sim.grid_config import GridConfig, subset
from cnep.pipeline.sim.grid_table import cell_rows, csv_text, pooled_table, read_rows
from cnep.pipeline.sim.validation import VALIDATION_RANGE, SelectionSettings
from cnep.recordings import read_summary
from cnep.recordings.constants import KIND_TRAJECTORY
from cnep.sim.statistics import wilson

SIM = all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA)


def test_grid_arguments_become_its_settings_and_the_executor_its_address():
    args = build_parser().parse_args(
        ["sim", "grid", "--out", "g", "--tasks", "obstacle", "--sets", "3,4", "--per-behaviour", "5,10",
         "--executor", "dask", "tcp://10.0.0.5:8786"]
    )  # fmt: skip
    from cnep.pipeline.cli.executor import executor_of

    kind, address = executor_of(args)
    config = config_of(GridConfig, args, out=args.out, executor=kind, address=address, tasks=tuple(args.tasks))
    assert (config.tasks, config.sets, config.per_behaviour) == (("obstacle",), (3, 4), (5, 10))
    assert (config.executor, config.address) == ("dask", "tcp://10.0.0.5:8786")
    assert config.train_seeds == GridConfig.train_seeds and config.reported_seeds == range(0, GridConfig.episodes)
    assert GridConfig(out=Path("g")).tasks == SIM_TASKS  # the tasks with settings of their own


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_the_grids_feature_components_train_every_units_models(tmp_path):
    from cnep.pipeline.sim.grid import task_config
    from cnep.pipeline.sim.stage import training_jobs
    from cnep.sim.tasks import find_task

    config = GridConfig(out=tmp_path, tasks=("obstacle",), feature_components=0)
    unit = task_config(config, find_task("obstacle", config.env_version), tmp_path / "run", 0, 3, 10)
    jobs = training_jobs(unit, unit.out)
    assert set(jobs) == {"CNEP-seed3", "CNMP-seed3"}
    assert all(job.model.feature_components == 0 for job in jobs.values())
    assert config.shared()["feature_components"] == 0  # a rerun into the grid's folder with another value is refused


def test_grid_refuses_reported_seeds_among_the_validation_seeds_and_other_bad_settings(tmp_path, capsys):
    start = VALIDATION_RANGE[0]
    with pytest.raises(
        PipelineError, match=f"episode seeds {start - 5} to {start + 4}, which meet the validation seeds"
    ):
        GridConfig(out=Path("g"), episode_seed=start - 5, episodes=10)
    assert GridConfig(out=Path("g"), episode_seed=start - 10, episodes=10).reported_seeds.stop == start
    with pytest.raises(PipelineError, match="--train-seeds takes distinct values"):
        GridConfig(out=Path("g"), train_seeds=(1, 1))
    with pytest.raises(PipelineError, match="--executor local takes no address"):
        GridConfig(out=Path("g"), address="tcp://h:1")
    with pytest.raises(PipelineError, match="--executor dask tcp://h: no port"):
        GridConfig(out=Path("g"), executor="dask", address="tcp://h")
    with pytest.raises(ConfigError, match="feature_components must be a whole number >= 0"):
        GridConfig(out=Path("g"), feature_components=-1)
    with pytest.raises(PipelineError, match="--tasks must name tasks"):
        GridConfig(out=Path("g"), tasks=("juggling",))
    with pytest.raises(PipelineError, match="--tasks must name tasks among obstacle, pick-place"):
        GridConfig(out=Path("g"), tasks=("pick-cube",))  # a task without settings of its own to train with
    out = tmp_path / "g"
    assert main(["sim", "grid", "--out", str(out), "--episode-seed", str(start)]) == 2
    assert "which meet the validation seeds" in capsys.readouterr().err and not out.exists()


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_a_cluster_where_no_scheduler_answers_is_refused_before_any_set_is_made(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    import cnep.pipeline.sim.grid as grid
    from cnep.pipeline.evaluate import addresses
    from tests.pipeline.test_executors import silent_listener

    def no_work(*args, **kwargs):
        raise AssertionError("a set was made before the cluster was reached")

    monkeypatch.setattr(addresses, "CONNECT_SECONDS", 1.0)
    monkeypatch.setattr(grid, "generate_demonstrations", no_work)
    out = tmp_path / "g"
    with silent_listener() as port:
        address = f"tcp://127.0.0.1:{port}"
        capsys.readouterr()
        assert main(["-q", "sim", "grid", "--out", str(out), "--executor", "dask", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--executor dask {address}: the listener there sent no Dask handshake" in err[0], err
    assert not out.exists()


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
@pytest.mark.parametrize(
    "text, says",
    [
        ("{oops", "cannot read this file of the grid's"),
        ("[" * 100_000 + "]" * 100_000, "cannot read this file of the grid's \\(nested 100000 levels deep"),
        ('{"a": "' + "a" * (17 << 20) + '"}', "cannot read this file of the grid's \\(larger than the 16777216 bytes"),
        ("[1, 2]", "this file of the grid's holds one JSON object, got list"),
    ],
    ids=["not JSON", "too deep", "17 MB", "a list"],
)
def test_a_grid_file_that_cannot_be_read_is_one_line_naming_it(tmp_path, capsys, text, says):
    import cnep.pipeline.sim.grid as grid

    out = tmp_path / "g"
    out.mkdir()
    (out / grid.GRID_FILE).write_text(text)
    capsys.readouterr()
    assert main(["-q", "sim", "grid", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(f"{out / grid.GRID_FILE}: {says}", err[0]), err
    assert sorted(p.name for p in out.iterdir()) == [grid.GRID_FILE]
    set_folder = tmp_path / "set"
    set_folder.mkdir()
    for set_text in (text, '{"behaviours": 5}'):
        (set_folder / grid.SET_FILE).write_text(set_text)
        with pytest.raises(
            PipelineError, match=f"^{set_folder / grid.SET_FILE}: .*delete {set_folder} to make the set"
        ):
            grid.make_set(GridConfig(out=out), None, 0, set_folder)
    for cell_text in (text, '{"results": {"online": 5}}'):
        (tmp_path / "cell.json").write_text(cell_text)
        with pytest.raises(PipelineError, match=f"^{tmp_path / 'cell.json'}: .*delete it to run its cell again"):
            grid.rows_of_cell(tmp_path / "cell.json")


def cell(seed: int, successes: int, entropy: float | None) -> dict:
    """A cell file's contents: an obstacle CNEP of 10 online episodes, `successes` of them successful."""
    rows = [{"seed": i, "success": i < successes} for i in range(10)]
    lo, hi = wilson(successes, 10)
    rates = {"episodes": 10, "success": successes / 10, "success_ci": [lo, hi], "entropy": entropy,
             "left": 0.5, "left_ci": [0.2, 0.8], "min_clearance_m": 0.01, "ms": {}, "per_episode": rows}  # fmt: skip
    return {"task": "obstacle", "set": 0, "per_behaviour": 5, "demonstrations": 10, "model": "CNEP",
            "train_seed": seed, "results": {"online": rates}}  # fmt: skip


def test_csv_rows_hold_each_cell_and_the_table_pools_its_runs_with_a_wilson_interval():
    rows = [*cell_rows(cell(0, 5, 0.9)), *cell_rows(cell(1, 10, None))]
    assert [(r["train_seed"], r["protocol"], r["condition"], r["episode_seeds"]) for r in rows] == [
        (0, "online", "", "0-9"),
        (1, "online", "", "0-9"),
    ]
    assert list(rows[0])[10:15] == ["success", "success_lo", "success_hi", "entropy", "left"]
    again = read_rows(csv_text(rows))
    assert [float(r["success"]) for r in again] == [0.5, 1.0] and again[1]["entropy"] == ""
    lo, hi = wilson(15, 20)
    line = pooled_table(again).splitlines()[-1]
    assert line == f"| obstacle | CNEP | 5 | online | - | 2 | 20 | 75.0% [{lo:.1%}, {hi:.1%}] | 50%-100% | 0.90 |"


needs_sim = pytest.mark.skipif(not SIM, reason="the sim extra is not installed")


def test_a_subset_takes_the_first_demonstrations_of_each_behaviour():
    behaviours = ["left", "left", "right", "left", "right", "right"]
    assert subset(behaviours, ("left", "right"), 2) == [0, 1, 2, 4]
    assert subset(behaviours, ("left", "right", "up"), 4) == [0, 1, 2, 3, 4, 5]


@needs_sim
def test_a_set_holding_features_of_all_its_demonstrations_is_refused_in_one_line(tmp_path):
    import cnep.pipeline.sim.grid as grid

    folder = tmp_path / "sets/obstacle-set0"
    (folder / "trajectories").mkdir(parents=True)
    config = GridConfig(out=tmp_path, tasks=("obstacle",), sets=(0,), train_seeds=(0,), per_behaviour=(2,))
    with pytest.raises(PipelineError, match=r"obstacle-set0: this set holds the features of all its demonstrations"):
        grid.make_set(config, None, 0, folder)
    assert sorted(p.name for p in folder.iterdir()) == ["trajectories"]


@needs_sim
@pytest.mark.slow  # a demonstration set, two trainings, two exports, two policies in the loop
def test_a_tiny_grid_runs_end_to_end_and_a_rerun_does_no_work(tmp_path, monkeypatch, few_calibration_frames):
    import cnep.pipeline.sim.grid as grid

    # the smallest choice, 2 candidates on 1 validation episode per condition: tests/sim/test_selection.py tests it
    few = SelectionSettings(candidates=2, selection_episodes=1)
    monkeypatch.setattr("cnep.pipeline.extract.stage.DEFAULT_VIEWS", 1)  # one view: a quicker extraction
    task_config = grid.task_config
    monkeypatch.setattr(grid, "task_config", lambda *args: replace(task_config(*args), selection=few))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    out = tmp_path / "grid"
    config = GridConfig(
        out=out, tasks=("obstacle",), sets=(0,), train_seeds=(0,), per_behaviour=(2,), train_steps=5, episodes=1,
        max_steps=5, weights="random", offline=True, workers=0, quiet=True,
    )  # fmt: skip
    first = grid.run_grid(config)
    assert (first.cells, first.ran) == (2, 2)
    assert [(r["model"], r["demonstrations"], r["episodes"], r["episode_seeds"]) for r in first.rows] == [
        ("CNEP", 4, 1, "0-0"),
        ("CNMP", 4, 1, "0-0"),
    ]
    assert json.loads((out / "sets/obstacle-set0/set.json").read_text())["behaviours"].count("left") == 2
    run = out / "runs/obstacle-set0-d2-seed0"
    trajectories = sorted((run / "trajectories").glob("*.mcap"))
    assert len(trajectories) == 4
    # the subset extracted as `cnep extract` extracts 4 recordings: the rule's views, its own calibrated weights
    assert [read_summary(path, KIND_TRAJECTORY).views for path in trajectories] == [views_for(4)] * 4
    assert (run / "extractor.pt").samefile(out / "sets/obstacle-set0-d2/extractor.pt")
    assert not (out / "sets/obstacle-set0/trajectories").exists()
    for model in ("cnep", "cnmp"):  # each kept checkpoint chosen from its candidates on the validation episodes
        kept = json.loads((run / "checkpoints" / f"{model}-seed0" / "config.json").read_text())["selection"]
        assert kept["seeds"] == {"first": VALIDATION_RANGE[0], "last": VALIDATION_RANGE[0]}
        assert len(kept["candidates"]) == few.candidates
    # the policies name the task's version, which `cnep sim eval` runs them on
    assert task_and_version(policy_task(run / "policies" / "cnep-seed0")) == ("obstacle", config.env_version)
    table = (out / grid.TABLE_FILE).read_text()
    assert read_rows((out / grid.CSV_FILE).read_text()) == read_rows(csv_text(first.rows)) and "| CNMP | 2 |" in table

    def no_work(*args, **kwargs):
        raise AssertionError("a rerun of a finished grid made a set or ran a unit")

    with monkeypatch.context() as patched:
        patched.setattr(grid, "generate_demonstrations", no_work)
        patched.setattr(grid, "extract_features", no_work)
        patched.setattr(grid, "run_grid_unit", no_work)
        again = grid.run_grid(config)
    assert (again.cells, again.ran, again.table) == (2, 0, first.table)

    (out / "cells/obstacle-set0-d2-seed0-CNMP.json").unlink()  # a cell lost: made again from the kept checkpoint
    checkpoint = run / "checkpoints/cnmp-seed0/model.safetensors"
    trained = checkpoint.stat().st_mtime_ns
    with monkeypatch.context() as patched:
        patched.setattr(grid, "generate_demonstrations", no_work)
        third = grid.run_grid(config)
    assert third.ran == 1 and checkpoint.stat().st_mtime_ns == trained
    assert [r["success"] for r in third.rows] == [r["success"] for r in first.rows]

    with pytest.raises(PipelineError, match="this grid ran with --episodes 1; give the same"):
        grid.run_grid(GridConfig(**{**config.__dict__, "episodes": 2}))
