"""Wrong or unusual data is refused with one line naming the file and the row, or accepted with a warning that
says what was assumed, the assumption written into the recording's metadata; natural CSV headers just work."""

from __future__ import annotations

import json
import logging
import shutil

import cv2
import numpy as np
import pytest

from cnep.pipeline.cli.main import main
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.recordings import RecordingError, read_demonstration
from cnep.recordings.csv_motion import CsvColumns
from tests.recordings.sources import baxter_csv, motion, video

NATURAL = "t,x,y,z,qx,qy,qz,qw,gripper"


def natural_csv(path, t_s, header=NATURAL, scale=1.0, edit=None):
    """A CSV with the usual column names, times `t_s` in the unit of `scale` (1: seconds), sampling `motion`."""
    pose, grip = motion(np.asarray(t_s, dtype=float))
    rows = [[t * scale, *p, g] for t, p, g in zip(t_s, pose, grip)]
    if edit:
        edit(rows)
    path.write_text("\n".join([header, *(",".join(repr(float(v)) for v in row) for row in rows)]) + "\n")
    return path


def run(path, tmp_path, **options):
    return read_demonstration(ingest(IngestConfig(src=path, out=tmp_path / "out", quiet=True, **options))[0].output)


def test_a_natural_header_in_seconds_is_read_and_the_unit_said(tmp_path, caplog):
    t = np.arange(40) * 0.05  # 20 Hz
    path = natural_csv(tmp_path / "a.csv", t)
    with caplog.at_level(logging.INFO):
        demo = run(path, tmp_path)
    np.testing.assert_array_equal(demo.timestamps_ns, np.round(t * 1e9).astype(np.int64))
    assert demo.episode.fps == pytest.approx(20.0)
    assert demo.episode.extra["time_unit"] == "s (inferred: median step 0.05 s = 20 Hz)"
    assert f"{path}: time unit s (inferred: median step 0.05 s = 20 Hz)" in caplog.text


@pytest.mark.parametrize("header,scale", [("time_ms,x,y,z,qx,qy,qz,qw,gripper", 1e3), ("timestamp [us]", 1e6)])
def test_a_unit_in_the_time_columns_name_is_used(tmp_path, header, scale):
    header = header if "," in header else header + NATURAL[1:]
    demo = run(natural_csv(tmp_path / "a.csv", np.arange(10) * 0.05, header, scale), tmp_path)
    assert demo.episode.fps == pytest.approx(20.0) and demo.episode.extra["time_unit"].startswith(
        f"{'ms' if scale == 1e3 else 'us'} (named in the header"
    )


def test_a_stated_unit_that_gives_an_implausible_rate_is_refused(tmp_path):
    path = natural_csv(tmp_path / "a.csv", np.arange(40) * 0.05)
    with pytest.raises(RecordingError) as raised:
        run(path, tmp_path, columns=CsvColumns(time_unit="ms"))
    assert str(path) in str(raised.value) and "a rate of 2e+04 Hz" in str(raised.value)
    assert "(in s it would be 20 Hz)" in str(raised.value) and "--column time_unit=UNIT" in str(raised.value)


def test_the_missing_column_error_lists_every_key(tmp_path, capsys):
    path = natural_csv(tmp_path / "a.csv", np.arange(5) * 0.05, "t,x,y,z,qx,qy,qz,orientation,gripper")
    assert main(["-q", "ingest", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "missing CSV columns (qw: q_w or qw or quat_w or orientation_w)" in err
    assert "keys: time, time_unit, x, y, z, qx, qy, qz, qw, gripper" in err


def test_two_columns_for_one_key_must_be_chosen(tmp_path):
    path = natural_csv(tmp_path / "a.csv", np.arange(5) * 0.05, "t,x,y,z,qx,qy,qz,qw,gripper")
    path.write_text(path.read_text().replace("t,x,", "t,p_x,").replace("\n", ",0\n").replace("gripper,0", "gripper,x"))
    with pytest.raises(RecordingError, match=r"columns \['p_x', 'x'\] could each be the 'x' column"):
        run(path, tmp_path)


def test_a_value_far_outside_the_recording_is_refused_naming_file_and_step(tmp_path):
    def spike(rows):
        rows[7][1] = 1e30

    path = natural_csv(tmp_path / "a.csv", np.arange(20) * 0.05, edit=spike)
    with pytest.raises(RecordingError) as raised:
        run(path, tmp_path)
    text = str(raised.value)
    assert text.startswith(f"{path}: step 7 (t = 0.350 s): x is 1e+30, far outside the rest of the recording")
    assert not list((tmp_path / "out").rglob("*.mcap"))


def test_a_robot_that_waits_then_moves_fast_is_not_an_outlier(tmp_path):
    def wait_then_move(rows):
        for i, row in enumerate(rows):
            row[1] = 0.4 if i < 36 else 0.4 + 0.3 * (i - 35)  # still for 36 steps, then 1.2 m in four
            row[8] = 0.0 if i < 39 else 100.0  # the gripper closes once, at the end

    demo = run(natural_csv(tmp_path / "a.csv", np.arange(40) * 0.05, edit=wait_then_move), tmp_path)
    assert demo.pose[-1, 0] == pytest.approx(1.6) and demo.gripper[-1] == 100.0


def test_a_quaternion_far_from_the_others_length_is_refused(tmp_path):
    def shrink(rows):
        rows[5][4:8] = [0.55 * q for q in rows[5][4:8]]

    path = natural_csv(tmp_path / "a.csv", np.arange(20) * 0.05, edit=shrink)
    with pytest.raises(RecordingError) as raised:
        run(path, tmp_path)
    assert str(raised.value).startswith(f"{path}: line 7: the quaternion has length 0.55 where the others have about 1")


def test_quaternions_all_of_another_length_are_normalised_with_a_note(tmp_path, caplog):
    def double(rows):
        for row in rows:
            row[4:8] = [2 * q for q in row[4:8]]

    with caplog.at_level(logging.WARNING):
        demo = run(natural_csv(tmp_path / "a.csv", np.arange(20) * 0.05, edit=double), tmp_path)
    np.testing.assert_allclose(np.linalg.norm(demo.pose[:, 3:], axis=1), 1.0)
    assert demo.episode.extra["quaternions"] == "normalised from lengths 2-2"
    assert "the quaternions have length about 2, not 1" in caplog.text


def test_a_video_that_ends_before_the_motion_is_warned_and_noted(tmp_path, caplog):
    src = tmp_path / "demo"
    src.mkdir()
    baxter_csv(src / "pose.csv", np.arange(40) * 50.0)  # 2 s at 20 Hz
    video(src / "camera.avi", 17, 20.0)  # 0.8 s
    with caplog.at_level(logging.WARNING):
        demo = run(src, tmp_path)
    assert demo.n_steps == 17
    assert f"{src / 'camera.avi'}: the frames end before the motion does" in caplog.text
    assert "22 CSV rows of" in caplog.text
    assert demo.episode.extra["coverage"].startswith("frames 0.000-0.800 s, motion 0.000-1.950 s")


def test_frames_that_change_size_are_warned_and_noted(tmp_path, caplog):
    src = tmp_path / "demo"
    src.mkdir()
    baxter_csv(src / "pose.csv", np.arange(6) * 50.0)
    for i, size in enumerate([32, 32, 32, 16, 16, 48]):
        cv2.imwrite(str(src / f"frame_{i}.png"), np.full((size, size, 3), 40 * i, np.uint8))
    with caplog.at_level(logging.WARNING):
        demo = run(src, tmp_path)
    assert demo.episode.extra["frame_sizes"] == (
        "32x32 at 3 step(s) from step 0; 16x16 at 2 step(s) from step 3; 48x48 at 1 step(s) from step 5"
    )
    assert f"{src}: the frames change size" in caplog.text


def test_a_video_that_cannot_be_opened_says_why_and_ffmpeg_stays_quiet(tmp_path, capfd):
    src = tmp_path / "demo"
    src.mkdir()
    baxter_csv(src / "pose.csv", np.arange(20) * 50.0)
    whole = tmp_path / "whole.mp4"
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter_fourcc(*"mp4v"), 20.0, (32, 32))
    for i in range(40):
        writer.write(np.full((32, 32, 3), 5 * i, np.uint8))
    writer.release()
    data = whole.read_bytes()
    (src / "camera.mp4").write_bytes(data[: len(data) // 2])  # its index (moov) was never written
    capfd.readouterr()
    assert main(["-q", "ingest", str(src), "--out", str(tmp_path / "out")]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{src / 'camera.mp4'}: cannot open this video (FFmpeg: moov atom not found)" in err[0]


def test_a_lerobot_dataset_whose_info_json_does_not_parse_is_named(tmp_path):
    pytest.importorskip("pyarrow")
    from tests.recordings.lerobot_sources import build_lerobot

    root = build_lerobot(tmp_path / "ds")
    info = root / "meta" / "info.json"
    info.write_text(info.read_text()[:-5])
    with pytest.raises(RecordingError, match=rf"{info}: cannot read as JSON"):
        ingest(IngestConfig(src=root, out=tmp_path / "out", quiet=True))


def test_a_json_encoded_foxglove_channel_names_the_encodings_cnep_reads(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "json.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("foxglove.PoseInFrame", "jsonschema", b"{}")
        channel = writer.register_channel("/ee/pose", "json", schema)
        for i in range(3):
            message = {"timestamp": {"sec": i, "nsec": 0}, "frame_id": "base", "pose": {}}
            writer.add_message(channel, i * 10**9, json.dumps(message).encode(), i * 10**9)
        writer.finish()
    with pytest.raises(RecordingError) as raised:
        ingest(IngestConfig(src=path, out=tmp_path / "out", quiet=True))
    text = str(raised.value)
    assert "'/ee/pose' holds json-encoded messages of schema 'foxglove.PoseInFrame'" in text
    assert "it reads protobuf-encoded Foxglove schemas" in text and "cdr-encoded ROS 2" in text


def test_the_baxter_format_still_needs_no_options(tmp_path):
    demo = run(baxter_csv(tmp_path / "b.csv", 6 + 12.0 * np.arange(30)), tmp_path)
    assert demo.episode.extra["time_unit"].startswith("ms (inferred: median step 12 ms = 83.33 Hz)")
    shutil.rmtree(tmp_path / "out")
