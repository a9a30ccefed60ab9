"""`--force` replaces only what the same command recorded writing (pipeline/ownership.py, cnep.outputs.record).

Per command: a user's files of every kind the command writes (a JSON object, JSON lines, an MCAP written by cnep,
torch and safetensors weights, a Rerun file, a PNG signed by matplotlib, a folder) planted in its output survive
`--force`; one at an output's path, or inside a folder the command replaces, is refused with one line naming a
file the command did not write; the command's own recorded outputs are replaced. Another command's outputs, a file
that appears while a command runs, a folder named like the one a run sets an output aside in, and anything inside a
command's input are never deleted or written.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import pytest

from cnep.outputs import RECORD_FILE, foreign_files, read_record, record_written, recorded_by, writing_as
from cnep.recordings import write_demonstration
from tests.pipeline.test_contract import QUICK_EVALUATE, TINY_TRAINING, assert_one_line, run_cli, world  # noqa: F401
from tests.recordings.factories import demonstration_factory


def user_mcap(path: Path, seed: int = 7) -> None:
    """An MCAP file cnep's recording layer wrote, but for the user, outside any command."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_demonstration(path, demonstration_factory(12, frames=False, seed=seed, episode_id="mine"))


def plant(folder: Path) -> dict[Path, bytes]:
    """The user's own files, one of every kind a cnep command writes, in `folder`; returns {path: bytes}."""
    import numpy as np
    import torch
    from safetensors.numpy import save_file

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "my_notes.json").write_text('{"a": 1}')
    (folder / "log.jsonl").write_text("{}\n")
    (folder / "my_config.json").write_text('{"format_version": 1, "model": {}}')
    user_mcap(folder / "mine.mcap")
    torch.save({"w": torch.zeros(2)}, folder / "weights.pt")
    save_file({"w": np.zeros(2, dtype=np.float32)}, str(folder / "my_model.safetensors"))
    (folder / "mine.rrd").write_bytes(b"RRF2" + bytes(60))
    (folder / "plot.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"tEXtSoftware\x00Matplotlib version3.9" + bytes(40))
    (folder / "mine").mkdir()
    (folder / "mine" / "summary.json").write_text('{"recordings": [], "total": {}}')
    return snapshot(folder)


def snapshot(folder: Path) -> dict[Path, bytes]:
    """Every file under `folder` but cnep's bookkeeping, with its bytes."""
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and not p.name.startswith(".")}


def unchanged(files: dict[Path, bytes]) -> bool:
    return all(path.is_file() and path.read_bytes() == data for path, data in files.items())


def refused(argv: list, capsys, command: str, named: list[Path]) -> str:
    """Run ARGV --force: exit 2 and one line naming one of `named`."""
    code, err = run_cli([*argv, "--force"], capsys)
    assert code == 2, err
    line = assert_one_line(err, command, "--force", "never deletes your own files")
    assert any(f"{p}:" in line for p in named), line
    return line


# One output file per command that writes files into a folder: (argv, the output the test plants a file at, the
# user's own content for that path).
FILE_OUTPUTS = {
    "ingest": lambda w, t: (["ingest", w.csv, "--out", t / "out"], t / "out" / "a.mcap", user_mcap),
    "extract": lambda w, t: (["extract", w.demos, "--out", t / "out"], t / "out" / "d1.mcap", user_mcap),
    "repair": lambda w, t: (
        ["repair", w.truncated_demo, t / "out" / "fixed.mcap"],
        t / "out" / "fixed.mcap",
        user_mcap,
    ),
    "replay": lambda w, t: (
        ["replay", w.ckpt, w.trajs / "t0.mcap", "--out", t / "out" / "r.rrd", "--no-live"],
        t / "out" / "r.experts.json",
        lambda p: p.write_text(json.dumps({"checkpoint": "mine", "recordings": []})),
    ),
    "run": lambda w, t: (
        ["run", w.ckpt, w.ckpt_demo, "--out", t / "out" / "r.rrd", "--fast"],
        t / "out" / "r.rrd",
        lambda p: p.write_bytes(b"RRF2" + bytes(100)),
    ),
    "evaluate": lambda w, t: (
        ["evaluate", *QUICK_EVALUATE, "--out", t / "out"],
        t / "out" / "comparison.json",
        lambda p: p.write_text(json.dumps({"table": 1, "settings": {}, "paper_note": "mine"})),
    ),
}


@pytest.mark.parametrize("command", FILE_OUTPUTS)
def test_force_replaces_only_the_files_the_command_recorded(world, tmp_path, capsys, command, one_thread):  # noqa: F811
    argv, target, mine = FILE_OUTPUTS[command](world, tmp_path)
    planted = plant(tmp_path / "out")
    mine(target)  # the user's own file of the output's kind, where the command writes
    before = snapshot(tmp_path / "out")
    refused(argv, capsys, command, [target, *planted])  # no record: the folder is the user's
    assert snapshot(tmp_path / "out") == before

    if command == "evaluate":  # too slow to run twice here: a table recorded as its run records it
        target.write_text(json.dumps({"table": "comparison", "settings": {}, "paper_note": "cnep's"}))
        with writing_as(command):
            record_written([target])
    else:
        target.unlink()
        code, err = run_cli([*argv, "--force"], capsys)
        assert code == 0, err
        assert unchanged(planted) and target.is_file()
        assert target.name in read_record(target.parent)  # what it wrote is on the folder's record
        assert foreign_files(tmp_path / "out", recorded_by(command)) == sorted(planted)  # and nothing else is

        code, err = run_cli([*argv, "--force"], capsys)  # its own recorded output: replaced
        assert code == 0, err
        assert unchanged(planted)

    mine(target)  # the user's file at that path now: the record names the path, but not these bytes
    before = snapshot(tmp_path / "out")
    line = refused(argv, capsys, command, [target])
    assert line.startswith(f"cnep {command}: error: {target}:")
    assert snapshot(tmp_path / "out") == before


# Commands whose output is a folder replaced as a whole: (argv, the folder).
FOLDER_OUTPUTS = {
    "train": lambda w, t: (["train", w.trajs, "--out", t / "out" / "ckpt", *TINY_TRAINING], t / "out" / "ckpt"),
    "export": lambda w, t: (["export", w.ckpt, "--out", t / "out" / "policy"], t / "out" / "policy"),
}


@pytest.mark.parametrize("command", FOLDER_OUTPUTS)
def test_force_replaces_a_folder_only_when_it_holds_nothing_else(world, tmp_path, capsys, command, one_thread):  # noqa: F811
    argv, folder = FOLDER_OUTPUTS[command](world, tmp_path)
    assert run_cli(argv, capsys)[0] == 0
    written = snapshot(folder)
    for name, data in plant(tmp_path / "kinds").items():  # one kind at a time, each refused
        into = folder / name.relative_to(tmp_path / "kinds")
        into.parent.mkdir(exist_ok=True)
        into.write_bytes(data)
        refused(argv, capsys, command, [into])
        assert unchanged({into: data, **written})
        shutil.rmtree(into.parent) if into.parent != folder else into.unlink()
    code, err = run_cli([*argv, "--force"], capsys)  # nothing else in it: replaced
    assert code == 0, err


def test_a_checkpoint_without_a_record_is_the_users(world, tmp_path, capsys):  # noqa: F811
    """A folder without a record (an older cnep's, a copy without its record) is the user's, however it looks."""
    out = tmp_path / "ckpt"
    shutil.copytree(world.ckpt, out)
    (out / RECORD_FILE).unlink()
    before = snapshot(out)
    refused(["train", world.trajs, "--out", out, *TINY_TRAINING], capsys, "train", list(before))
    assert snapshot(out) == before


def test_extract_save_weights_replaces_only_its_recorded_weights(world, tmp_path, capsys):  # noqa: F811
    import torch

    weights = tmp_path / "w" / "extractor.pt"
    weights.parent.mkdir()
    torch.save({"w": torch.zeros(2)}, weights)  # a torch file, but the user's
    (tmp_path / "w" / "notes.json").write_text("{}")
    argv = ["extract", world.demos, "--out", tmp_path / "out", "--weights", "random", "--save-weights", weights]
    before = snapshot(tmp_path / "w")
    refused(argv, capsys, "extract", [weights, tmp_path / "w" / "notes.json"])
    assert snapshot(tmp_path / "w") == before


def test_the_demo_repro_loses_nothing(tmp_path, capsys):
    m = tmp_path / "m"
    (m / "checkpoints").mkdir(parents=True)
    (m / "checkpoints" / "my_notes.json").write_text('{"a":1}\n')
    (m / "checkpoints" / "log.jsonl").write_text("{}\n")
    before = snapshot(m)
    refused(["demo", "--quick", "--out", m], capsys, "demo", list(before))
    assert snapshot(m) == before


def test_the_demo_never_deletes_a_home_like_folder(world, tmp_path, capsys):  # noqa: F811
    home = tmp_path / "home"
    user_mcap(home / "demos" / "mine.mcap")
    user_mcap(home / "trajectories" / "mine.mcap", seed=3)
    shutil.copytree(world.ckpt, home / "checkpoints" / "mine")
    (home / "summary.json").write_text('{"out": "mine", "rrd": [], "checkpoints": {}}')
    planted = {**plant(home / "replays"), **snapshot(home)}
    refused(["demo", "--quick", "--out", home], capsys, "demo", list(planted))
    assert unchanged(planted)


@writing_as("demo")
def test_a_demo_folder_is_all_recorded_and_nothing_else_is_deleted(quick_demo, tmp_path):
    from cnep.outputs import FOLDER_LOCK
    from cnep.pipeline.demo.stage import remove_outputs
    from cnep.pipeline.errors import PipelineError

    copy = tmp_path / "demo"
    shutil.copytree(quick_demo, copy)
    assert foreign_files(copy, recorded_by("demo")) == []  # every file the demo wrote is on its folder's record
    for name, data in plant(tmp_path / "kinds").items():  # each kind, at each depth the demo writes, is refused
        for into in (copy, copy / "checkpoints", copy / "checkpoints" / "cnep", copy / "demos" / "train"):
            path = into / name.relative_to(tmp_path / "kinds")
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(data)
            with pytest.raises(PipelineError, match=f"^{path}: --force deletes only what an earlier demo"):
                remove_outputs(copy, copy / FOLDER_LOCK)
            assert path.read_bytes() == data
            shutil.rmtree(path.parent) if path.parent.name == "mine" else path.unlink()
    remove_outputs(copy, copy / FOLDER_LOCK)
    assert [p.name for p in copy.iterdir()] == []


def test_a_deeply_nested_record_is_no_record_not_a_crash(tmp_path):
    """A record nested thousands of levels deep is read with a limit: the folder holds nothing of cnep's, no
    RecursionError."""
    deep = "[" * 5000 + "]" * 5000
    (tmp_path / RECORD_FILE).write_text(deep)
    (tmp_path / "summary.json").write_text(deep)
    assert read_record(tmp_path) is None
    assert foreign_files(tmp_path, recorded_by("demo")) == [tmp_path / "summary.json"]


# --- what no command deletes: another command's outputs, a file that appears while it runs, a user's folder beside an
# --- output, anything inside its input --------------------------------------------------------------------------


def test_the_demo_replaces_only_what_a_demo_recorded_writing(quick_demo, world, tmp_path, capsys):  # noqa: F811
    """Another command's recorded outputs inside a demo folder, and a cnep MCAP copied into one of its folders that
    holds no record, are not the demo's: `cnep demo --force` refuses, and deletes nothing."""
    demo = tmp_path / "d"
    shutil.copytree(quick_demo, demo)
    assert run_cli(["ingest", world.csv, "--out", demo / "mydata"], capsys)[0] == 0  # recorded, by `cnep ingest`
    mine = snapshot(demo / "mydata")
    before = snapshot(demo)
    refused(["demo", "--quick", "--out", demo], capsys, "demo", list(mine))
    assert snapshot(demo) == before
    shutil.rmtree(demo / "mydata")
    shutil.copy(next((demo / "demos" / "train").glob("*.mcap")), demo / "demos" / "copied.mcap")
    before = snapshot(demo)
    refused(["demo", "--quick", "--out", demo], capsys, "demo", [demo / "demos" / "copied.mcap"])
    assert snapshot(demo) == before


def trained_copy(world, folder: Path) -> Path:  # noqa: F811
    """A checkpoint `cnep train` wrote (the world's, copied with its record) at `folder`."""
    shutil.copytree(world.ckpt, folder)
    return folder


def test_train_force_keeps_another_commands_outputs_inside_the_checkpoint(world, tmp_path, capsys, one_thread):  # noqa: F811
    ckpt = trained_copy(world, tmp_path / "ckpt")
    elsewhere = tmp_path / "runs" / "r.rrd"
    assert run_cli(["run", ckpt, world.ckpt_demo, "--out", elsewhere, "--fast"], capsys)[0] == 0
    shutil.move(tmp_path / "runs", ckpt / "runs")  # a run's outputs, with their record, moved into the checkpoint
    before = snapshot(ckpt)
    refused(["train", world.trajs, "--out", ckpt, *TINY_TRAINING], capsys, "train", list(snapshot(ckpt / "runs")))
    assert snapshot(ckpt) == before


def test_a_file_written_into_the_checkpoint_while_training_is_kept(world, tmp_path, capsys, monkeypatch, one_thread):  # noqa: F811
    """Ownership is checked again when the new checkpoint replaces the old one, not only when the run starts: a file
    that appeared meanwhile keeps the old checkpoint in place, and the finished one waits in the work folder."""
    import cnep.pipeline.train.stage as stage

    ckpt = trained_copy(world, tmp_path / "ckpt")
    save = stage.save_progress

    def save_and_write(*args, **kwargs):
        (ckpt / "thesis.tex").write_text("mine")
        return save(*args, **kwargs)

    monkeypatch.setattr(stage, "save_progress", save_and_write)
    argv = ["train", world.trajs, "--out", ckpt, *TINY_TRAINING]
    before = {**snapshot(ckpt), ckpt / "thesis.tex": b"mine"}
    line = refused(argv, capsys, "train", [ckpt / "thesis.tex"])
    assert "--resume" in line
    assert snapshot(ckpt) == before
    monkeypatch.setattr(stage, "save_progress", save)
    (ckpt / "thesis.tex").unlink()
    code, err = run_cli([*argv, "--force", "--resume"], capsys)  # the trained checkpoint is published
    assert code == 0, err
    assert snapshot(ckpt) != {p: b for p, b in before.items() if p.name != "thesis.tex"}
    assert not (tmp_path / ".ckpt.partial").exists()


@pytest.mark.parametrize("present", [True, False], ids=["output-present", "output-missing"])
def test_a_users_replaced_folder_beside_the_output_is_never_touched(world, tmp_path, capsys, present, one_thread):  # noqa: F811
    """A folder named like the one a run sets the old output aside in is the user's: neither deleted nor renamed."""
    ckpt = tmp_path / "ckpt"
    if present:
        trained_copy(world, ckpt)
    mine = {}
    for name in (".ckpt.replaced", ".policy.replaced"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "thesis.tex").write_text("mine")
        mine[tmp_path / name / "thesis.tex"] = b"mine"
    code, err = run_cli(["train", world.trajs, "--out", ckpt, *TINY_TRAINING, "--force"], capsys)
    assert code == 0, err
    code, err = run_cli(["export", ckpt, "--out", tmp_path / "policy", "--force"], capsys)
    assert code == 0, err
    assert unchanged(mine) and (ckpt / "config.json").is_file() and (tmp_path / "policy" / "manifest.json").is_file()


def test_a_users_file_in_the_work_folder_beside_the_checkpoint_is_one_line_and_kept(world, tmp_path, capsys, caplog):  # noqa: F811
    """A `.CK.partial` folder holding a file training did not write: refused in one line, no word of removing it."""
    mine = {tmp_path / ".ckpt.partial" / "notes.txt": b"mine"}
    (tmp_path / ".ckpt.partial").mkdir()
    (tmp_path / ".ckpt.partial" / "notes.txt").write_bytes(b"mine")
    code, err = run_cli(["train", world.trajs, "--out", tmp_path / "ckpt", *TINY_TRAINING], capsys)
    assert code == 2
    assert_one_line(err, "train", f"{tmp_path / '.ckpt.partial' / 'notes.txt'}: ", "did not write")
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []  # the error line alone
    assert unchanged(mine) and not (tmp_path / "ckpt").exists()


INSIDE_INPUT = {  # argv writing into the checkpoint or policy it reads
    "run": lambda w, ck: ["run", ck, w.demos / "d0.mcap", "--out", ck / "runs" / "r.rrd", "--fast"],
    "replay": lambda w, ck: ["replay", ck, w.trajs / "t0.mcap", "--out", ck / "r.rrd", "--no-live"],
    "export": lambda w, ck: ["export", ck, "--out", ck / "policy"],
    "extract": lambda w, ck: ["extract", w.demos, "--out", w.demos / "trajectories"],
    "train": lambda w, ck: ["train", w.trajs, "--out", w.trajs / "ckpt", *TINY_TRAINING],
}


@pytest.mark.parametrize("command", INSIDE_INPUT)
def test_no_command_writes_inside_its_input(world, tmp_path, capsys, command, one_thread):  # noqa: F811
    ckpt = trained_copy(world, tmp_path / "ckpt")
    inputs = [ckpt, world.demos, world.trajs]
    before = {folder: snapshot(folder) for folder in inputs}
    code, err = run_cli(INSIDE_INPUT[command](world, ckpt), capsys)
    assert code == 2, err
    assert_one_line(err, command, "--out", "inside the input")
    assert {folder: snapshot(folder) for folder in inputs} == before
    assert not any(p.name.startswith(".") and "lock" in p.name for folder in inputs for p in folder.rglob("*"))
