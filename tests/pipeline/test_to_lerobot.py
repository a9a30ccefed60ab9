"""`cnep to-lerobot`: demonstrations -> a LeRobot v3.0 dataset that `cnep ingest` reads back with every frame and
value; a set of demonstrations that cannot make one dataset is refused before anything is written."""

import json
import logging
import re

import numpy as np
import pytest

pytest.importorskip("pyarrow")
pytest.importorskip("av")

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.ingest.stage import IngestConfig, ingest  # noqa: E402
from cnep.recordings import read_demonstration, write_demonstration  # noqa: E402
from cnep.recordings.lerobot import LerobotMapping  # noqa: E402
from cnep.runtime.frames import decode_frame  # noqa: E402
from tests.recordings.lerobot_sources import build_lerobot, command_of, recorded_demonstration, state_of  # noqa: E402

LOSSLESS = ["--codec", "h264", "--crf", "0", "--pix-fmt", "yuv444p"]  # lossless in YUV: only RGB <-> YUV rounding


def demonstration_files(folder, demos):
    folder.mkdir()
    return [write_demonstration(folder / f"{demo.episode.episode_id}.mcap", demo) for demo in demos]


def cnep(*argv) -> int:
    return main(["-q", *map(str, argv)])


def read_back(dataset, out, **mapping):
    """The dataset ingested again, in episode order."""
    done = ingest(IngestConfig(src=dataset, out=out, lerobot=LerobotMapping(**mapping), quiet=True))
    return [read_demonstration(d.output) for d in done]


def pixel_errors(demo, back) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the largest and the mean absolute difference (0-255) between the demonstration's and the read-back
    frame; and per frame the mean difference to every frame of the demonstration (which step it looks like)."""
    ours = np.stack([decode_frame(f).astype(int) for f in demo.frames])  # (T, H, W, 3)
    theirs = np.stack([decode_frame(f).astype(int) for f in back.frames])
    largest = np.abs(ours - theirs).max(axis=(1, 2, 3))
    to_every = np.abs(theirs[:, None] - ours[None]).mean(axis=(2, 3, 4))  # (T, T): read-back frame i vs source j
    return largest, to_every


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two demonstrations as ingest writes them from a robot (epoch times with jitter, float64 motion, frames)."""
    root = tmp_path_factory.mktemp("recorded")
    demos = [recorded_demonstration(0, 5, task="pick"), recorded_demonstration(1, 6, task="place")]
    return root, demonstration_files(root / "demos", demos), demos


def test_a_round_trip_keeps_every_value_time_and_frame(recorded, tmp_path):
    _, files, demos = recorded
    assert cnep("to-lerobot", files[0].parent, "--out", tmp_path / "ds", *LOSSLESS) == 0
    for demo, back in zip(demos, read_back(tmp_path / "ds", tmp_path / "back")):
        # values as LeRobot stores them (float32); quaternions renormalised when read, as every reader does
        np.testing.assert_array_equal(back.pose[:, :3], demo.pose[:, :3].astype(np.float32))
        np.testing.assert_allclose(back.pose[:, 3:], demo.pose[:, 3:], atol=1e-7)
        np.testing.assert_array_equal(back.gripper, demo.gripper.astype(np.float32))
        seconds = ((demo.timestamps_ns - demo.timestamps_ns[0]) / 1e9).astype(np.float32)  # LeRobot's timestamp
        np.testing.assert_array_equal(back.timestamps_ns, np.round(seconds.astype(np.float64) * 1e9))
        np.testing.assert_array_less(np.abs(back.timestamps_ns - (demo.timestamps_ns - demo.timestamps_ns[0])), 500)
        assert back.episode.task == demo.episode.task and back.episode.fps == demo.episode.fps
        largest, _ = pixel_errors(demo, back)
        assert largest.max() <= 6  # the RGB <-> YUV rounding and the reader's JPEG encoding (quality 90)


def test_lerobots_default_video_keeps_each_frame_within_the_codecs_loss(recorded, tmp_path):
    _, files, demos = recorded
    assert cnep("to-lerobot", *files, "--out", tmp_path / "ds") == 0  # AV1, CRF 30, yuv420p
    info = json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())
    assert info["features"]["observation.images.rgb"]["info"]["video.codec"] == "av1"
    for demo, back in zip(demos, read_back(tmp_path / "ds", tmp_path / "back")):
        _, to_every = pixel_errors(demo, back)
        assert np.diag(to_every).max() <= 3  # mean absolute difference of a frame, of 255
        np.testing.assert_array_equal(to_every.argmin(axis=1), np.arange(demo.n_steps))  # each is its own step's


def test_the_commanded_gripper_of_a_lerobot_dataset_survives_the_round_trip(tmp_path):
    source = build_lerobot(tmp_path / "source", "v3.0", episodes=2, steps=5, command=True)
    demos = read_back(source, tmp_path / "demos")
    commands = [[command_of(e, i) for i in range(5)] for e in range(2)]
    assert [d.gripper.tolist() for d in demos] == commands  # what a policy learns: the command, not the opening
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds", *LOSSLESS) == 0
    assert [d.gripper.tolist() for d in read_back(tmp_path / "ds", tmp_path / "back")] == commands
    measured = read_back(tmp_path / "ds", tmp_path / "state", gripper_from="state")
    assert [d.gripper.tolist() for d in measured] == commands  # the written state holds the demonstration's gripper
    opening = read_back(source, tmp_path / "opening", gripper_from="state")
    np.testing.assert_allclose(opening[1].gripper, [state_of(1, i)[7] for i in range(5)])


def test_demonstrations_at_different_rates_need_the_datasets_rate(tmp_path, capsys):
    files = demonstration_files(
        tmp_path / "demos", [recorded_demonstration(0, 3, fps=10.0), recorded_demonstration(1, 3, fps=12.5)]
    )
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(files[1]) in err and "give it with --fps HZ" in err
    assert not (tmp_path / "ds").exists()
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds", "--fps", "10") == 0
    assert json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())["fps"] == 10


def test_frames_in_some_demonstrations_only_are_refused_unless_motion_only(tmp_path, capsys):
    without = recorded_demonstration(1, 3)
    without.frames = None
    files = demonstration_files(tmp_path / "demos", [recorded_demonstration(0, 3), without])
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(files[1]) in err and '--camera ""' in err
    assert not (tmp_path / "ds").exists()
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds", "--camera", "") == 0
    assert all(d.frames is None for d in read_back(tmp_path / "ds", tmp_path / "back"))


def test_steps_off_the_rate_are_kept_and_said(recorded, tmp_path, caplog):
    _, files, _ = recorded  # their steps jitter by up to 4 ms around 10 Hz
    with caplog.at_level(logging.WARNING):
        assert cnep("to-lerobot", *files, "--out", tmp_path / "ds", *LOSSLESS) == 0
    assert "2 of 2 demonstrations" in caplog.text and "torchcodec" in caplog.text


def test_the_camera_is_named_as_asked(recorded, tmp_path):
    _, files, _ = recorded
    assert cnep("to-lerobot", files[0], "--out", tmp_path / "ds", "--camera", "front", *LOSSLESS) == 0
    assert (tmp_path / "ds" / "videos" / "observation.images.front").is_dir()


@pytest.mark.parametrize(
    "option, value, says",
    [
        ("--fps", "inf", "--fps inf: the dataset's rate must be from 0.1 to 10000 Hz"),
        ("--fps", "1e300", "--fps 1e\\+300: the dataset's rate must be from 0.1 to 10000 Hz"),
        ("--fps", "nan", "--fps nan: the dataset's rate must be from 0.1 to 10000 Hz"),
        ("--fps", "0", "--fps 0: the dataset's rate must be from 0.1 to 10000 Hz"),
        ("--camera", "a" * 300, "--camera: the feature observation.images.CAMERA names a folder .* this one has 319"),
    ],
    ids=["fps inf", "fps 1e300", "fps nan", "fps 0", "camera of 300 characters"],
)
def test_an_option_past_what_a_dataset_holds_is_one_line_before_any_work(tmp_path, capsys, option, value, says):
    demonstration_files(tmp_path / "demos", [recorded_demonstration(0, 3)])
    capsys.readouterr()
    assert cnep("to-lerobot", tmp_path / "demos", "--out", tmp_path / "ds", option, value) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(says, err[0]) and "internal error" not in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos"]
