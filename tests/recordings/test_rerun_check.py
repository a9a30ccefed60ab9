"""Files we write pass `rerun mcap check` (an independent MCAP reader shipped with rerun-sdk)."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.recordings import Event, add_events, write_demonstration, write_trajectory
from cnep.recordings.mcap_source import McapTopics
from cnep.recordings.repair import repair
from tests.recordings.factories import demonstration_factory, trajectory_factory
from tests.recordings.sources import baxter_csv, ros2_robot_mcap

RERUN = Path(sys.executable).parent / "rerun"


@pytest.fixture
def rerun_env(tmp_path, monkeypatch):
    if not RERUN.exists() and shutil.which("rerun") is None:
        pytest.fail("the rerun CLI (from rerun-sdk) is not installed next to the test interpreter")
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("HOME", str(home))


def rerun_check(path):
    exe = str(RERUN) if RERUN.exists() else "rerun"
    return subprocess.run([exe, "mcap", "check", str(path)], capture_output=True, text=True, timeout=120)


def test_written_files_pass_rerun_mcap_check(tmp_path, rerun_env):
    files = [
        write_demonstration(tmp_path / "demo.mcap", demonstration_factory(steps=10)),
        write_demonstration(tmp_path / "motion.mcap", demonstration_factory(steps=10, frames=False)),
        write_trajectory(tmp_path / "traj.mcap", trajectory_factory(steps=10, frames=True)),
        write_trajectory(tmp_path / "traj8.mcap", trajectory_factory(steps=10, features=False)),
    ]
    files.append(add_events(files[2], tmp_path / "events.mcap", [Event(1_700_000_000_100_000_000, {"expert": "1"})]))
    big = write_trajectory(tmp_path / "big.mcap", trajectory_factory(steps=400))
    big.write_bytes(big.read_bytes()[: big.stat().st_size * 3 // 4])
    files.append(repair(big, tmp_path / "repaired.mcap").dst)
    src = tmp_path / "raw"
    src.mkdir()
    baxter_csv(src / "baxter.csv", np.arange(20) * 12.0 + 6)
    ros2_robot_mcap(src / "ros2.mcap")
    topics = McapTopics(
        image="/cam/compressed", pose="/ee_pose", gripper="/joint_states", gripper_joint="gripper_joint"
    )
    files += [d.output for d in ingest(IngestConfig(src=src, out=tmp_path / "ingested", topics=topics, quiet=True))]
    assert len(files) == 8
    for path in files:
        out = rerun_check(path)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "ok" in out.stdout


def test_rerun_mcap_check_rejects_a_truncated_file(tmp_path, rerun_env):
    path = write_trajectory(tmp_path / "traj.mcap", trajectory_factory(steps=10))
    path.write_bytes(path.read_bytes()[:-200])
    out = rerun_check(path)
    assert out.returncode != 0 or "ok" not in out.stdout
