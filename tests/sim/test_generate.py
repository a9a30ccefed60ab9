"""The simulator's demonstrations are what a user's robot writes (frames + pose CSV), as its sensors recorded them,
and `cnep ingest` takes them."""

import importlib.util
import logging

import numpy as np
import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.sim.generate import CSV_FILE, generate_demonstrations, ingest_demonstrations  # noqa: E402
from cnep.recordings import read_demonstration  # noqa: E402
from cnep.sim.tasks import find_task  # noqa: E402


def test_generated_demonstrations_are_balanced_clean_and_ingested_as_a_users_recordings_quietly(tmp_path, caplog):
    made = generate_demonstrations(find_task("obstacle", 1), tmp_path / "recorded", 2, seed=3, quiet=True)
    assert sorted(made.behaviours) == ["left", "right"] and made.successes == 2
    folder = made.folders[0]
    frames = sorted(folder.glob("frame_*.png"))
    rows = (folder / CSV_FILE).read_text().splitlines()
    assert rows[0] == "t,x,y,z,qx,qy,qz,qw,gripper" and len(rows) == len(frames) + 1
    with caplog.at_level(logging.INFO, logger="cnep.recordings"):
        ingest_demonstrations(tmp_path / "recorded", tmp_path / "demos", find_task("obstacle", 1), quiet=True)
    assert not caplog.records  # the time unit is stated: no line per file about inferring it
    demo = read_demonstration(tmp_path / "demos" / f"{folder.name}.mcap")
    assert demo.frames is not None and len(demo.frames) == len(frames) and demo.episode.task == "obstacle-v1"
    assert len(frames) <= find_task("obstacle", 1).max_steps + 1  # the demonstrator's episode, ended at the goal
    # The orientation as the robot's sensors report it, off the gripper's unturned pose by their noise (about 1 deg).
    turned = np.abs(demo.pose[:, 3:7] - [0.0, 0.0, 0.0, 1.0]).max()
    assert 0 < turned < 0.05
