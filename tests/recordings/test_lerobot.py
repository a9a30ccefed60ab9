"""LeRobot datasets (v2.1, v3.0) in: frames, poses and tasks land on the right steps; bad datasets are refused whole."""

import json

import cv2
import numpy as np
import pytest

pytest.importorskip("pyarrow")
pytest.importorskip("av")

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.ingest.stage import IngestConfig, ingest  # noqa: E402
from cnep.recordings import RecordingError, read_demonstration  # noqa: E402
from cnep.recordings.lerobot import LerobotMapping, demonstration_from_lerobot, plan_lerobot  # noqa: E402
from cnep.recordings.lerobot_columns import quaternion_from_rpy  # noqa: E402
from tests.recordings.lerobot_sources import TASKS, build_lerobot, command_of, level_of, state_of  # noqa: E402

STEPS, FPS = 6, 10


def grey_levels(frames: list[bytes]) -> np.ndarray:
    return np.array([cv2.imdecode(np.frombuffer(f, np.uint8), cv2.IMREAD_COLOR).mean() for f in frames])


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
@pytest.mark.parametrize("image", [False, True], ids=["video", "parquet-images"])
def test_each_episode_becomes_a_demonstration_with_frames_at_the_parquet_times(tmp_path, version, image):
    src = build_lerobot(tmp_path / "ds", version, episodes=2, steps=STEPS, fps=FPS, image=image)
    done = ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))
    assert [d.output.name for d in done] == ["episode_000000.mcap", "episode_000001.mcap"]
    for e, item in enumerate(done):
        demo = read_demonstration(item.output)
        assert demo.episode.task == TASKS[e] and demo.episode.fps == FPS
        assert demo.episode.extra["format"] == f"lerobot {version}"
        seconds = np.float32(np.arange(STEPS) / FPS).astype(np.float64)  # LeRobot stores float32 seconds
        np.testing.assert_array_equal(demo.timestamps_ns, np.round(seconds * 1e9))
        expected = np.array([state_of(e, i) for i in range(STEPS)], dtype=np.float32).astype(np.float64)
        np.testing.assert_allclose(demo.pose, expected[:, :7], atol=1e-6)
        np.testing.assert_allclose(demo.gripper, expected[:, 7])
        # each frame is the one of its own step (levels 25 apart; H.264 moves them by <= 2)
        np.testing.assert_allclose(grey_levels(demo.frames), [level_of(e, i) for i in range(STEPS)], atol=3)


def test_av1_video_as_lerobot_records_by_default(tmp_path):
    av = pytest.importorskip("av")
    try:
        av.codec.Codec("libsvtav1", "w")
    except av.codec.codec.UnknownCodecError:
        pytest.skip("this PyAV build has no AV1 encoder")
    src = build_lerobot(tmp_path / "ds", "v3.0", episodes=2, steps=STEPS, size=64, codec="libsvtav1")
    for episode in plan_lerobot(src):
        demo = demonstration_from_lerobot(episode)
        np.testing.assert_allclose(grey_levels(demo.frames), [level_of(episode.index, i) for i in range(STEPS)], atol=3)


def test_roll_pitch_yaw_and_indices_map_to_the_same_pose(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v3.0", episodes=1, steps=4, rpy=True, pad=2)
    by_name = plan_lerobot(src)[0]  # names x y z roll pitch yaw, gripper found by name
    by_index = plan_lerobot(src, LerobotMapping(pose=tuple("012345"), gripper="6"))[0]
    np.testing.assert_array_equal(by_name.pose, by_index.pose)
    quat = np.array([state_of(0, i)[3:7] for i in range(4)], dtype=np.float32)  # the quaternion form of the same angles
    np.testing.assert_allclose(by_name.pose[:, 3:], quat, atol=1e-6)
    np.testing.assert_allclose(by_name.gripper, [0, 10, 20, 30])


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
def test_the_gripper_is_the_actions_command_where_the_action_names_it(tmp_path, version):
    src = build_lerobot(tmp_path / "ds", version, episodes=2, steps=5, command=True)
    commanded, measured = plan_lerobot(src), plan_lerobot(src, LerobotMapping(gripper_from="state"))
    for e, (by_action, by_state) in enumerate(zip(commanded, measured)):
        np.testing.assert_array_equal(by_action.gripper, [command_of(e, i) for i in range(5)])
        np.testing.assert_allclose(by_state.gripper, [state_of(e, i)[7] for i in range(5)])
        np.testing.assert_array_equal(by_action.pose, by_state.pose)  # the pose is the state's either way
    assert commanded[0].extra["columns"].endswith("gripper action[gripper]")
    assert measured[0].extra["columns"].endswith("gripper observation.state[gripper]")


def test_a_gripper_given_by_index_is_found_in_the_action_by_its_name(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v3.0", episodes=1, steps=5, rpy=True, pad=2, command=True)
    episode = plan_lerobot(src, LerobotMapping(pose=tuple("012345"), gripper="6"))[0]
    np.testing.assert_array_equal(episode.gripper, [command_of(0, i) for i in range(5)])


def test_an_unknown_gripper_source_is_refused():
    with pytest.raises(RecordingError, match="gripper source 'command': choose one of action, state"):
        LerobotMapping(gripper_from="command")


def test_rpy_follows_the_z_y_x_convention():
    rpy = np.array([[0.3, -0.2, 1.1]])
    x, y, z, w = quaternion_from_rpy(rpy)[0]
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    c, s = np.cos(rpy[0]), np.sin(rpy[0])
    rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    np.testing.assert_allclose(r, rz @ ry @ rx, atol=1e-12)


def test_motion_only_and_task_override(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v2.1", episodes=1, steps=3)
    ingest(IngestConfig(src=src, out=tmp_path / "out", task="my task", lerobot=LerobotMapping(camera=""), quiet=True))
    demo = read_demonstration(tmp_path / "out" / "episode_000000.mcap")
    assert demo.frames is None and demo.episode.task == "my task"


def _set_info(src, **changes):
    path = src / "meta" / "info.json"
    info = json.loads(path.read_text())
    info.update(changes)
    path.write_text(json.dumps(info))


@pytest.mark.parametrize("version", ["v2.1", "v3.0"])
@pytest.mark.parametrize(
    "case, args, expected",
    [
        ("missing camera", ["--camera", "observation.images.wrist"], "no camera 'observation.images.wrist'"),
        ("unknown version", [], "codebase_version 'v1.6' is not supported"),
        ("short state", ["--gripper", "8"], "index 8 is outside 'observation.state', a vector of 8 values"),
        ("empty episode", [], "episode 1): the episode has no frames"),
    ],
)
def test_a_bad_dataset_gives_one_error_line_and_writes_nothing(tmp_path, capsys, version, case, args, expected):
    src = build_lerobot(
        tmp_path / "ds", version, episodes=3, steps=4, empty_episode=1 if case == "empty episode" else None
    )
    if case == "unknown version":
        _set_info(src, codebase_version="v1.6")
    out = tmp_path / "out"
    assert main(["-q", "ingest", str(src), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err and str(src) in err
    assert not out.exists()


def test_state_rows_shorter_than_the_info_says_are_refused(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v2.1", episodes=1, steps=3)
    _set_info(
        src,
        features={
            **json.loads((src / "meta" / "info.json").read_text())["features"],
            "observation.state": {"dtype": "float32", "shape": [10], "names": None},
        },
    )
    with pytest.raises(RecordingError, match="holds 8 values per row, the pose/gripper mapping reads index 9"):
        plan_lerobot(src, LerobotMapping(pose=tuple("0123456"), gripper="9"))


def test_unnamed_state_needs_an_explicit_pose(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v2.1", episodes=1, steps=3)
    _set_info(
        src,
        features={
            **json.loads((src / "meta" / "info.json").read_text())["features"],
            "observation.state": {"dtype": "float32", "shape": [8], "names": ["motors"]},
        },
    )
    with pytest.raises(RecordingError, match="--pose x,y,z,qx,qy,qz,qw"):
        plan_lerobot(src)
    assert len(plan_lerobot(src, LerobotMapping(pose=tuple("0123456"), gripper="7"))) == 1


def test_video_that_disagrees_with_the_timestamps_is_refused(tmp_path):
    src = build_lerobot(tmp_path / "ds", "v2.1", episodes=1, steps=4, fps=10)
    from tests.recordings.lerobot_sources import grey_frame, write_video

    video = next((src / "videos").rglob("*.mp4"))
    write_video(video, [grey_frame(50, 32)] * 4, fps=5)  # frames at 0, 0.2, 0.4 s: no frame at 0.1 s
    with pytest.raises(RecordingError, match="no video frame within 0.1 ms of 0.1000 s"):
        ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))


def test_a_dataset_in_a_sub_folder_is_found_beside_other_recordings(tmp_path):
    from tests.recordings.sources import baxter_csv

    build_lerobot(tmp_path / "in" / "lab_a", "v3.0", episodes=2, steps=3)
    baxter_csv(tmp_path / "in" / "arm.csv", np.arange(5) * 10.0)
    done = ingest(IngestConfig(src=tmp_path / "in", out=tmp_path / "out", quiet=True))
    assert sorted(d.output.relative_to(tmp_path / "out").as_posix() for d in done) == [
        "arm.mcap",
        "lab_a/episode_000000.mcap",
        "lab_a/episode_000001.mcap",
    ]


def test_v30_episode_metadata_without_the_video_offset_is_refused(tmp_path):
    import pyarrow.parquet as pq

    src = build_lerobot(tmp_path / "ds", "v3.0", episodes=2, steps=3)
    path = src / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
    pq.write_table(pq.read_table(path).drop_columns(["videos/observation.images.cam/from_timestamp"]), path)
    with pytest.raises(RecordingError, match="episode 0 has no 'videos/observation.images.cam/from_timestamp'"):
        plan_lerobot(src)
