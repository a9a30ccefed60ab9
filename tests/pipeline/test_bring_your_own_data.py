"""A team's own data through the whole pipeline: ingest -> extract -> train (tiny) -> replay, per input format.

The commands are the ones docs/how-to/lerobot-dataset.md and docs/how-to/ros-bag.md show (with test-sized settings).
"""

from pathlib import Path

import numpy as np
import pytest

from cnep.pipeline.cli.main import main
from cnep.pipeline.replay.decisions import read_decisions
from cnep.recordings import read_trajectory

TINY_TRAIN = [
    "--steps",
    "6",
    "--val-every",
    "3",
    "--warmup-steps",
    "1",
    "--batch-size",
    "2",
    "--encoder-widths",
    "8,8",
    "--expert-widths",
    "8,8",
    "--seed",
    "0",
]


@pytest.fixture(autouse=True)
def quiet_rerun(tmp_path, monkeypatch, one_thread):
    """The rerun CLI writes analytics under HOME unless CI is set."""
    (tmp_path / "home").mkdir()
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))


@pytest.fixture(autouse=True)
def one_view(monkeypatch):
    """One view of the frames where `cnep extract` draws its default: the views' path at a quarter of the rule's
    extraction (tests/pipeline/test_extract.py tests the views themselves)."""
    monkeypatch.setattr("cnep.pipeline.extract.stage.DEFAULT_VIEWS", 1)


def run_pipeline(src: Path, work: Path, *ingest_args: str) -> list[Path]:
    """Run the four stages as a user would; returns the trajectory files."""
    assert main(["-q", "ingest", str(src), "--out", str(work / "demos"), *ingest_args]) == 0
    assert (
        main(
            [
                "-q",
                "extract",
                str(work / "demos"),
                "--out",
                str(work / "traj"),
                "--weights",
                "random",
                "--backend",
                "eager",
                "--threads",
                "1",
            ]
        )
        == 0
    )
    trajectories = sorted((work / "traj").rglob("*.mcap"))
    assert main(["-q", "train", str(work / "traj"), "--out", str(work / "ckpt"), *TINY_TRAIN]) == 0
    assert (
        main(
            [
                "-q",
                "replay",
                str(work / "ckpt"),
                *map(str, trajectories),
                "--out",
                str(work / "replay.rrd"),
                "--no-live",
            ]
        )
        == 0
    )
    decisions = read_decisions(work / "replay.rrd")
    rrds = sorted(work.glob("replay-*.rrd"))  # one .rrd per recording (pipeline.replay.stage.rrd_files)
    assert len(decisions["recordings"]) == len(trajectories) == len(rrds) and all(p.stat().st_size > 0 for p in rrds)
    return trajectories


@pytest.mark.slow
@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_lerobot_dataset_end_to_end(tmp_path, version):
    pytest.importorskip("pyarrow")
    pytest.importorskip("av")
    from tests.recordings.lerobot_sources import build_lerobot, state_of

    src = build_lerobot(tmp_path / "dataset", version, episodes=2, steps=6, fps=10)
    trajectories = run_pipeline(src, tmp_path / "work")
    assert [t.name for t in trajectories] == ["episode_000000.mcap", "episode_000001.mcap"]
    for e, path in enumerate(trajectories):
        traj = read_trajectory(path)
        assert traj.has_features and traj.n_steps == 6 and len(traj.frames) == 6
        expected = np.array([state_of(e, i) for i in range(6)], dtype=np.float32)
        np.testing.assert_allclose(traj.pose, expected[:, :7], atol=1e-6)
        np.testing.assert_allclose(traj.gripper, expected[:, 7])


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_ros_bags_end_to_end(tmp_path, kind):
    pytest.importorskip("rosbags")
    from tests.recordings.rosbag_sources import FRAME_TIMES_S, T0_NS, write_ros1_bag, write_ros2_bag
    from tests.recordings.sources import motion

    (tmp_path / "bags").mkdir()
    for k in range(2):  # two demonstrations: two bag files, or two bag folders
        if kind == "ros1":
            write_ros1_bag(tmp_path / "bags" / f"run{k}.bag", compressed=k == 1)
        else:
            write_ros2_bag(tmp_path / "bags" / f"run{k}", storage=("sqlite3", "mcap")[k])
    trajectories = run_pipeline(
        tmp_path / "bags",
        tmp_path / "work",
        "--image-topic",
        "/camera/rgb",
        "--pose-topic",
        "/ee/pose",
        "--gripper-topic",
        "/gripper",
        "--gripper-joint",
        "gripper",
    )
    assert [t.name for t in trajectories] == ["run0.mcap", "run1.mcap"]
    kept = FRAME_TIMES_S[:-1]
    pose, gripper = motion(kept)
    for path in trajectories:
        traj = read_trajectory(path)
        assert traj.has_features
        np.testing.assert_array_equal(traj.timestamps_ns, T0_NS + np.round(kept * 1e9).astype(np.int64))
        np.testing.assert_allclose(traj.pose, pose, atol=1e-6)
        np.testing.assert_allclose(traj.gripper, gripper, atol=1e-5)
