"""`--force` replaces only what a cnep command recorded writing (pipeline/ownership.py, cnep.outputs.record).

Per command: a user's files of every kind the command writes (a JSON object, JSON lines, an MCAP written by cnep,
torch and safetensors weights, a Rerun file, a PNG signed by matplotlib, a folder) planted in its output survive
`--force`; one at an output's path, or inside a folder the command replaces, is refused with one line naming a
file cnep did not write; the command's own recorded outputs are replaced.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from cnep.outputs import RECORD_FILE, read_record, record_written
from cnep.pipeline.ownership import foreign_files
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


def never(path: Path) -> bool:
    return False


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
    refused(argv, capsys, command, [target, *planted])  # no record: the folder holds more than cnep's kind
    assert snapshot(tmp_path / "out") == before

    if command == "evaluate":  # too slow to run twice here: a table recorded as its run records it
        target.write_text(json.dumps({"table": "comparison", "settings": {}, "paper_note": "cnep's"}))
        record_written([target])
    else:
        target.unlink()
        code, err = run_cli([*argv, "--force"], capsys)
        assert code == 0, err
        assert unchanged(planted) and target.is_file()
        assert target.name in read_record(target.parent)  # what it wrote is on the folder's record
        assert foreign_files(tmp_path / "out", never) == sorted(planted)  # and nothing else is

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


def test_a_checkpoint_written_before_records_is_replaced_only_when_it_holds_nothing_else(world, tmp_path, capsys):  # noqa: F811
    out = tmp_path / "ckpt"
    shutil.copytree(world.ckpt, out)
    (out / RECORD_FILE).unlink()
    (out / "my_notes.json").write_text('{"a": 1}')
    argv = ["train", world.trajs, "--out", out, *TINY_TRAINING]
    refused(argv, capsys, "train", [out / "my_notes.json"])
    (out / "my_notes.json").unlink()
    code, err = run_cli([*argv, "--force"], capsys)
    assert code == 0, err
    assert set(read_record(out)) == {"config.json", "model.safetensors", "training_log.jsonl"}


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


def test_a_demo_folder_is_all_recorded_and_nothing_else_is_deleted(quick_demo, tmp_path):
    from cnep.pipeline.demo.stage import remove_outputs
    from cnep.pipeline.errors import PipelineError

    copy = tmp_path / "demo"
    shutil.copytree(quick_demo, copy)
    assert foreign_files(copy, never) == []  # every file the demo wrote is on its folder's record
    for name, data in plant(tmp_path / "kinds").items():  # each kind, at each depth the demo writes, is refused
        for into in (copy, copy / "checkpoints", copy / "checkpoints" / "cnep", copy / "demos" / "train"):
            path = into / name.relative_to(tmp_path / "kinds")
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(data)
            with pytest.raises(PipelineError, match=f"^{path}: --force deletes only what an earlier demo"):
                remove_outputs(copy)
            assert path.read_bytes() == data
            shutil.rmtree(path.parent) if path.parent.name == "mine" else path.unlink()
    remove_outputs(copy)
    assert [p.name for p in copy.iterdir()] == []


def test_deeply_nested_json_is_a_users_file_not_a_crash(tmp_path):
    """A record or an output-like JSON nested thousands of levels deep is read with a limit: not cnep's, no
    RecursionError."""
    from cnep.pipeline.ownership import json_with

    deep = "[" * 5000 + "]" * 5000
    (tmp_path / RECORD_FILE).write_text(deep)
    (tmp_path / "summary.json").write_text(deep)
    assert read_record(tmp_path) is None
    assert not json_with("a summary", ())(tmp_path / "summary.json")
    assert foreign_files(tmp_path, json_with("a summary", ())) == [tmp_path / "summary.json"]
