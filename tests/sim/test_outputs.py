"""`cnep sim TASK --out O` and `cnep sim eval --out E` write their folder as every command writes one: assembled
beside it and renamed into place when complete. Stopped (SIGTERM, Ctrl-C, a full disk) before a stage finished, they
leave the folder as it was, a user's files in it included, and nothing half-made; run again, they finish (a stopped
`cnep sim` that finished stages keeps them: tests/sim/test_resume.py); `eval`
never writes inside the policy it reads. The stages' own work is stood in for here (tests/sim/test_stage.py runs them
for real)."""

import errno
import importlib.util
import json
import os

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import cnep.pipeline.sim.evaluate as sim_eval  # noqa: E402
import cnep.pipeline.sim.stage as sim_stage  # noqa: E402
from cnep.outputs import write_output, writing_as  # noqa: E402
from cnep.pipeline.contract import Terminated  # noqa: E402
from cnep.pipeline.sim.figure import FIGURE_FILE  # noqa: E402
from cnep.pipeline.sim.partial import SUMMARY_FILE  # noqa: E402
from tests.outputs.test_outputs import dead_pid  # noqa: E402
from tests.pipeline.test_contract import assert_one_line, run_cli  # noqa: E402


def half_done(folder, stop: BaseException | None):
    """What a stage leaves in `folder` before `stop` is raised (None: it finishes): a recording and a figure, each
    written as the closed loop writes them (atomically, named in their folder's record)."""
    (folder / "episodes").mkdir(exist_ok=True)
    write_output(folder / "episodes" / "CNEP-seed0-planned-seed0.rrd", b"RRF2" + bytes(60))
    write_output(folder / FIGURE_FILE, b"\x89PNG" + bytes(60))
    if stop is not None:
        raise stop
    return {"table": "the table", "features": "random", "models": {}}


def names(folder) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


@pytest.fixture
def world_ckpt(motion_world, tmp_path_factory):
    """A checkpoint `cnep train` wrote (the motion world's, copied: a test may not write the shared one)."""
    import shutil

    return shutil.copytree(motion_world.ckpt, tmp_path_factory.mktemp("policy") / "ckpt")


STOPS = {
    "SIGTERM": (Terminated(), 143, "terminated (SIGTERM); nothing half-written was kept"),
    "Ctrl-C": (KeyboardInterrupt(), 130, "interrupted; nothing half-written was kept"),
    "full disk": (OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "x"), 2, "free some disk space"),
}


@pytest.mark.parametrize("stop", STOPS)
def test_a_stopped_sim_leaves_its_folder_as_it_was_with_the_users_files_and_runs_again(
    tmp_path, capsys, monkeypatch, stop
):
    out = tmp_path / "sim"
    error, status, said = STOPS[stop]

    def stages(config, task, run):
        out.mkdir(exist_ok=True)
        (out / "notes.txt").write_text("mine")  # the user, while it runs
        return half_done(run.work, error)

    monkeypatch.setattr(sim_stage, "_run_stages", stages)
    code, err = run_cli(["sim", "obstacle", "--out", out], capsys)
    assert code == status and said in assert_one_line(err, "sim")
    assert names(tmp_path) == ["sim", "sim/notes.txt"] and (out / "notes.txt").read_text() == "mine"
    (out / "notes.txt").unlink()
    monkeypatch.setattr(sim_stage, "_run_stages", lambda config, task, run: half_done(run.work, None))
    code, err = run_cli(["sim", "obstacle", "--out", out], capsys)  # again, into the folder left empty
    assert code == 0, err
    assert names(out) == [
        ".cnep-record.json",
        FIGURE_FILE,
        "episodes",
        "episodes/.cnep-record.json",
        "episodes/CNEP-seed0-planned-seed0.rrd",
        SUMMARY_FILE,
    ]
    assert json.loads((out / SUMMARY_FILE).read_text())["table"] == "the table"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim"]  # no work folder, no lock left beside it


def test_a_file_put_into_the_folder_while_the_sim_ran_keeps_it_in_place(tmp_path, capsys, monkeypatch):
    out = tmp_path / "sim"
    out.mkdir()  # new and empty: the sim may write it

    def stages(config, task, run):
        (out / "notes.txt").write_text("mine")
        return half_done(run.work, None)

    monkeypatch.setattr(sim_stage, "_run_stages", stages)
    code, err = run_cli(["sim", "obstacle", "--out", out], capsys)
    assert code == 2 and "cnep never deletes your own files" in assert_one_line(err, "sim", "--out")
    assert names(tmp_path) == ["sim", "sim/notes.txt"]


def test_the_work_folder_a_sim_killed_in_its_first_stage_left_goes_with_the_next_run(tmp_path, capsys, monkeypatch):
    out = tmp_path / "sim"
    left = tmp_path / ".sim.partial"  # kill -9 in the middle of generating: no stage finished
    (left / "recorded").mkdir(parents=True)
    with writing_as("sim obstacle"):
        write_output(left / "recorded" / "poses.csv", b"t,x")
    (left / "recorded" / f".frame.png.{dead_pid()}-abcdef.tmp").write_bytes(b"\x89PNG")
    (tmp_path / ".sim.lock").write_text(json.dumps({"pid": dead_pid()}))
    monkeypatch.setattr(sim_stage, "_run_stages", lambda config, task, run: half_done(run.work, None))
    code, err = run_cli(["sim", "obstacle", "--out", out], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim"] and (out / SUMMARY_FILE).is_file()
    assert not (out / "recorded").exists()  # the killed run's files went; nothing of theirs is in the new output


@pytest.mark.parametrize("stop", STOPS)
def test_a_stopped_sim_eval_keeps_nothing_half_made_and_runs_again(world_ckpt, tmp_path, capsys, monkeypatch, stop):
    out = tmp_path / "eval"
    error, status, said = STOPS[stop]
    monkeypatch.setattr(sim_eval, "_evaluate", lambda config, label, folder: half_done(folder, error))
    code, err = run_cli(["sim", "eval", world_ckpt, "--task", "obstacle", "--out", out], capsys)
    assert code == status and said in assert_one_line(err, "sim")
    assert names(tmp_path) == []  # no .rrd or episode.png without summary.json: nothing at all
    monkeypatch.setattr(sim_eval, "_evaluate", lambda config, label, folder: half_done(folder, None))
    monkeypatch.setattr(sim_eval, "_summary", lambda config, results: {"table": "the table"})
    code, err = run_cli(["sim", "eval", world_ckpt, "--task", "obstacle", "--out", out], capsys)
    assert code == 0, err
    assert {FIGURE_FILE, SUMMARY_FILE, "episodes"} <= set(os.listdir(out))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eval"]


def test_sim_eval_never_writes_inside_its_input(world_ckpt, tmp_path, capsys):
    code, err = run_cli(["sim", "eval", world_ckpt, "--task", "obstacle", "--out", world_ckpt / "eval"], capsys)
    assert code == 2
    assert_one_line(err, "sim", f"{world_ckpt / 'eval'}: ", "inside the input", "--out")
    assert not (world_ckpt / "eval").exists()


@pytest.mark.parametrize("command", ["sim", "sim eval"])
def test_a_full_disk_names_the_file_in_the_folder_asked_for_not_in_the_work_folder(
    world_ckpt, tmp_path, capsys, monkeypatch, command
):
    out = tmp_path / "out"

    def full(folder):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder / "episodes" / "CNEP-seed0.rrd"))

    monkeypatch.setattr(sim_stage, "_run_stages", lambda config, task, run: full(run.work))
    monkeypatch.setattr(sim_eval, "_evaluate", lambda config, label, folder: full(folder))
    argv = (
        ["sim", "obstacle", "--out", out]
        if command == "sim"
        else ["sim", "eval", world_ckpt, "--task", "obstacle", "--out", out]
    )
    code, err = run_cli(argv, capsys)
    line = assert_one_line(err, "sim", f"{out / 'episodes' / 'CNEP-seed0.rrd'}: No space left on device")
    assert code == 2 and ".tmp" not in line and names(tmp_path) == []
