"""LeRobot v3.0 datasets out: the files LeRobot lays out, their values, statistics and frames, and what is refused."""

import json

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
av = pytest.importorskip("av")

from cnep.recordings import RecordingError  # noqa: E402
from cnep.recordings.lerobot import demonstration_from_lerobot, plan_lerobot  # noqa: E402
from cnep.recordings.lerobot_video import VideoSettings  # noqa: E402
from cnep.recordings.lerobot_writer import LerobotWriter  # noqa: E402
from cnep.runtime.frames import decode_frame  # noqa: E402
from cnep.runtime.spec import STATE_NAMES  # noqa: E402
from tests.recordings.lerobot_sources import gradient_frames, recorded_demonstration  # noqa: E402

CAMERA = "observation.images.rgb"
LOSSLESS = VideoSettings(codec="h264", crf=0, pix_fmt="yuv444p")  # lossless in YUV: only RGB <-> YUV rounding


def write(root, demos, camera=CAMERA, video=LOSSLESS, **limits):
    with LerobotWriter(root, 10, camera, video, **limits) as writer:
        for demo in demos:
            writer.add(demo)
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three episodes of 5, 4 and 6 steps (tasks pick, place, pick), 32 x 32 frames, in one data and one video file."""
    demos = [
        recorded_demonstration(s, steps, task=task)
        for s, steps, task in ((0, 5, "pick"), (1, 4, "place"), (2, 6, "pick"))
    ]
    return write(tmp_path_factory.mktemp("lerobot") / "ds", demos), demos


def test_the_files_are_where_lerobot_lays_them_out(dataset):
    root, demos = dataset
    found = sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())
    assert found == [
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
        f"videos/{CAMERA}/chunk-000/file-000.mp4",
    ]
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (3, 15, 2)
    assert info["splits"] == {"train": "0:3"}
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    features = info["features"]
    for vector in ("observation.state", "action"):
        assert features[vector] == {"dtype": "float32", "shape": [8], "names": list(STATE_NAMES)}
    assert features[CAMERA]["shape"] == [32, 32, 3] and features[CAMERA]["dtype"] == "video"
    assert features[CAMERA]["info"]["video.codec"] == "h264" and features[CAMERA]["info"]["video.fps"] == 10
    assert {k: features[k]["dtype"] for k in ("timestamp", "frame_index", "episode_index", "index", "task_index")} == {
        "timestamp": "float32",
        "frame_index": "int64",
        "episode_index": "int64",
        "index": "int64",
        "task_index": "int64",
    }


def test_tasks_are_the_pandas_index_lerobot_reads(dataset):
    root, _ = dataset
    table = pq.read_table(root / "meta" / "tasks.parquet")
    assert table.to_pydict() == {"task_index": [0, 1], "__index_level_0__": ["pick", "place"]}
    assert json.loads(table.schema.metadata[b"pandas"])["index_columns"] == ["__index_level_0__"]


def test_each_step_is_a_row_and_each_episode_says_where_its_rows_and_frames_are(dataset):
    root, demos = dataset
    data = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")
    assert data.schema.field("observation.state").type == pa.list_(pa.float32(), 8)
    rows = data.to_pydict()
    assert rows["index"] == list(range(15)) and rows["episode_index"] == [0] * 5 + [1] * 4 + [2] * 6
    assert (
        rows["frame_index"] == [*range(5), *range(4), *range(6)] and rows["task_index"] == [0] * 5 + [1] * 4 + [0] * 6
    )
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert [(e["dataset_from_index"], e["dataset_to_index"], e["length"]) for e in episodes] == [
        (0, 5, 5),
        (5, 9, 4),
        (9, 15, 6),
    ]
    assert [e["tasks"] for e in episodes] == [["pick"], ["place"], ["pick"]]
    for episode, demo in zip(episodes, demos):  # each episode's video starts where the one before ended
        seconds = (demo.timestamps_ns - demo.timestamps_ns[0]) / 1e9
        assert episode[f"videos/{CAMERA}/to_timestamp"] == pytest.approx(
            episode[f"videos/{CAMERA}/from_timestamp"] + seconds[-1] + 0.1
        )
    assert episodes[1][f"videos/{CAMERA}/from_timestamp"] == episodes[0][f"videos/{CAMERA}/to_timestamp"]


def test_state_is_the_pose_and_gripper_and_action_the_next_pose_with_this_steps_gripper(dataset):
    root, demos = dataset
    rows = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    state, action = np.array(rows["observation.state"]), np.array(rows["action"])  # (15, 8) each
    demo = demos[1]
    ours = slice(5, 9)
    motion = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1).astype(np.float32)  # (4, 8)
    np.testing.assert_array_equal(state[ours], motion)
    np.testing.assert_array_equal(action[ours][:, :7], np.concatenate([motion[1:, :7], motion[-1:, :7]]))
    np.testing.assert_array_equal(action[ours][:, 7], motion[:, 7])
    np.testing.assert_array_equal(
        np.array(rows["timestamp"])[ours], ((demo.timestamps_ns - demo.timestamps_ns[0]) / 1e9).astype(np.float32)
    )


def test_the_statistics_are_the_datas(dataset):
    root, demos = dataset
    rows = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    stats = json.loads((root / "meta" / "stats.json").read_text())
    state = np.array(rows["observation.state"], dtype=np.float64)
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(axis=0))
    np.testing.assert_allclose(stats["observation.state"]["q90"], np.quantile(state, 0.9, axis=0))
    assert stats["index"]["max"] == [14] and stats["index"]["count"] == [15]
    pixels = np.concatenate([decode_frame(f).reshape(-1, 3) for demo in demos for f in demo.frames]) / 255  # (P, 3)
    camera = stats[CAMERA]
    assert np.array(camera["mean"]).shape == (3, 1, 1) and camera["count"] == [15]
    np.testing.assert_allclose(np.array(camera["std"]).ravel(), pixels.std(axis=0))
    np.testing.assert_allclose(np.array(camera["q01"]).ravel(), np.quantile(pixels, 0.01, axis=0))
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    np.testing.assert_allclose(episodes.to_pylist()[1]["stats/observation.state/min"], state[5:9].min(axis=0))
    assert episodes.schema.field("stats/index/max").type == pa.list_(pa.int64())  # an index's bounds are integers


def test_every_frame_is_in_the_video_at_its_steps_time(dataset):
    root, demos = dataset
    with av.open(str(root / "videos" / CAMERA / "chunk-000" / "file-000.mp4")) as video:
        decoded = [(float(f.time), f.to_ndarray(format="rgb24")) for f in video.decode(video=0)]
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    expected_times = [
        e[f"videos/{CAMERA}/from_timestamp"] + (t - demo.timestamps_ns[0]) / 1e9
        for e, demo in zip(episodes, demos)
        for t in demo.timestamps_ns
    ]
    np.testing.assert_allclose([t for t, _ in decoded], expected_times, atol=1e-6)
    sources = [decode_frame(f) for demo in demos for f in demo.frames]
    worst = max(np.abs(image.astype(int) - source).max() for (_, image), source in zip(decoded, sources))
    assert worst <= 2  # lossless in YUV: only the RGB <-> YUV rounding


def test_full_files_roll_over_to_the_next_and_read_back(tmp_path):
    demos = [recorded_demonstration(s, 3) for s in range(3)]
    root = write(tmp_path / "ds", demos, data_file_mb=1e-9, video_file_mb=1e-9)  # every file full after one episode
    assert sorted(str(p.relative_to(root / "data")) for p in (root / "data").rglob("*.parquet")) == [
        f"chunk-000/file-00{k}.parquet" for k in range(3)
    ]
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert [(e["data/file_index"], e[f"videos/{CAMERA}/file_index"]) for e in episodes] == [(0, 0), (1, 1), (2, 2)]
    assert {e[f"videos/{CAMERA}/from_timestamp"] for e in episodes} == {0.0}  # each video starts its own file
    for episode, demo in zip(plan_lerobot(root), demos):
        back = demonstration_from_lerobot(episode)
        np.testing.assert_array_equal(back.gripper, demo.gripper.astype(np.float32))
        assert len(back.frames) == 3


def test_motion_only_writes_no_video(tmp_path):
    root = write(tmp_path / "ds", [recorded_demonstration(0, 3)], camera=None)
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["video_path"] is None and not (root / "videos").exists()
    assert not any(f["dtype"] == "video" for f in info["features"].values())
    assert demonstration_from_lerobot(plan_lerobot(root)[0]).frames is None


def test_frames_of_another_size_are_refused_and_nothing_is_left(tmp_path):
    small, large = recorded_demonstration(0, 3, size=32), recorded_demonstration(1, 3, size=48)
    with pytest.raises(RecordingError, match=r"frame 0 is 48x48 pixels, the dataset's frames 32x32"):
        write(tmp_path / "ds", [small, large])
    assert not (tmp_path / "ds").exists()


def test_an_encoder_that_refuses_the_frame_size_says_what_to_choose(tmp_path):
    demo = recorded_demonstration(0, 3)
    demo.frames = gradient_frames(3, size=33)
    with pytest.raises(RecordingError, match=r"refuses 33x33 frames in yuv420p .*even width and height"):
        write(tmp_path / "ds", [demo], video=VideoSettings(codec="h264"))
    assert not (tmp_path / "ds").exists()


def test_a_video_aborted_on_a_full_disk_prints_nothing(tmp_path, capfd):
    """The disk fills while another file is written (the parquet data): the aborted muxer's trailer and seeks would
    fail again, and PyAV would print the failures it drops after the command's error line."""
    import os

    from cnep.recordings.lerobot_video import VideoFile

    video = VideoFile(tmp_path / "v.mp4", 64, 48, 10.0, VideoSettings(codec="h264"))
    rng = np.random.default_rng(0)
    for k in range(30):  # noise, which the encoder cannot shrink: the muxer has bytes left to write
        video.add(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), k / 10)
    full = os.open("/dev/full", os.O_WRONLY)  # every write of the file from now on: No space left on device
    try:
        os.dup2(full, video._file.fileno())
        capfd.readouterr()
        video.abort()
    finally:
        os.close(full)
    assert capfd.readouterr().err == ""
