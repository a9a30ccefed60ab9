"""JSON a user hands cnep, nested thousands of levels deep or too large, is one line and exit 2 in every command
that reads it (before, a deep one ended in "internal error (RecursionError)")."""

import pytest

from cnep.pipeline.cli.main import main
from cnep.recordings import write_demonstration, write_trajectory
from cnep.runtime.jsonfile import MAX_BYTES
from tests.recordings.factories import demonstration_factory, trajectory_factory

DEEP = "[" * 5000 + "]" * 5000


@pytest.fixture
def files(tmp_path):
    write_demonstration(tmp_path / "demo.mcap", demonstration_factory(steps=5))
    write_trajectory(tmp_path / "traj.mcap", trajectory_factory(steps=5, features=False))
    for folder in ("checkpoint", "policy", "lerobot/meta"):
        (tmp_path / folder).mkdir(parents=True)
    return tmp_path


CASES = {  # command -> (the JSON file it reads, its arguments)
    "replay": ("checkpoint/config.json", ["replay", "checkpoint", "traj.mcap", "--out", "r.rrd", "--no-live"]),
    "export": ("checkpoint/config.json", ["export", "checkpoint", "--out", "p"]),
    "run": ("policy/manifest.json", ["run", "policy", "demo.mcap", "--out", "r.rrd"]),
    "ingest": ("lerobot/meta/info.json", ["ingest", "lerobot", "--out", "demos"]),
    "train": ("settings.json", ["train", "traj.mcap", "--out", "c", "--config", "settings.json"]),
}


@pytest.mark.parametrize("text", [DEEP, " " * (MAX_BYTES + 1)], ids=["deep", "large"])
@pytest.mark.parametrize("command", CASES)
def test_hostile_json_is_one_line_naming_the_file(files, capsys, monkeypatch, command, text):
    name, argv = CASES[command]
    (files / name).write_text(text)
    monkeypatch.chdir(files)
    capsys.readouterr()
    assert main(["-q", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    said = "nested 5000 levels deep" if text == DEEP else f"larger than the {MAX_BYTES} bytes"
    assert len(err) == 1 and name in err[0] and said in err[0], err
    assert "internal error" not in err[0]
