import hashlib
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnep.outputs import RECORD_FILE
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.recordings import RecordingError, read_demonstration
from cnep.recordings.adapters import FrameTiming, demonstration_from_csv
from cnep.recordings.csv_motion import CsvColumns
from cnep.recordings.mcap_source import McapTopics
from tests.outputs.test_outputs import dead_pid
from tests.recordings.sources import (
    baxter_csv,
    images,
    jpeg_of,
    motion,
    robot_mcap,
    robot_samples,
    ros2_robot_mcap,
    video,
)


def tree_digest(folder):
    return {
        p.relative_to(folder): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def baxter_times(n, seed=0):
    """Irregular ms times like the Baxter recordings (10-22 ms apart), starting at 6 ms."""
    rng = np.random.default_rng(seed)
    return 6 + np.concatenate([[0], np.cumsum(rng.integers(10, 23, size=n - 1))]).astype(float)


def test_baxter_folder_motion_only_out_of_the_box(tmp_path):
    src = tmp_path / "first"
    (src / "start_end").mkdir(parents=True)
    times = {"0": baxter_times(40, 0), "start_end/demo_a": baxter_times(30, 1)}
    for name, t in times.items():
        baxter_csv(src / f"{name}.csv", t)
    (src / "data.png").write_bytes(b"\x89PNG not a frame")  # a plot beside the data is ignored
    before = tree_digest(src)
    done = ingest(IngestConfig(src=src, out=tmp_path / "out", task="avoid", quiet=True))
    assert tree_digest(src) == before
    assert sorted(d.source.episode_id for d in done) == sorted(times)
    for name, t in times.items():
        demo = read_demonstration(tmp_path / "out" / f"{name}.mcap")
        pose, grip = motion(t / 1000)
        np.testing.assert_array_equal(demo.timestamps_ns, (t * 1e6).astype(np.int64))
        np.testing.assert_allclose(demo.pose, pose, atol=1e-12)
        np.testing.assert_allclose(demo.gripper, grip, atol=1e-12)
        assert demo.frames is None
        assert demo.episode.episode_id == name and demo.episode.task == "avoid"
        assert demo.episode.fps == pytest.approx(1000 / np.median(np.diff(t)))


def test_one_numbered_image_per_row_keeps_csv_times(tmp_path):
    src = tmp_path / "demo"
    src.mkdir()
    t = baxter_times(12)
    baxter_csv(src / "pose.csv", t)
    images(src, 12, ".png")
    demo = ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))
    back = read_demonstration(demo[0].output)
    np.testing.assert_array_equal(back.timestamps_ns, (t * 1e6).astype(np.int64))
    np.testing.assert_allclose(back.pose, motion(t / 1000)[0], atol=1e-12)
    import cv2

    # frame_10 and frame_11 come after frame_9 (numeric, not text order); brightness encodes the index
    levels = [cv2.imdecode(np.frombuffer(f, np.uint8), cv2.IMREAD_GRAYSCALE).mean() for f in back.frames]
    np.testing.assert_allclose(levels, [(i * 20) % 256 for i in range(12)], atol=2)


def test_video_frames_get_interpolated_pose(tmp_path):
    src = tmp_path / "demo"
    src.mkdir()
    t = baxter_times(80)  # ~1.3 s of poses at ~60-100 Hz
    baxter_csv(src / "pose.csv", t)
    video(src / "cam.avi", 60, fps=25.0)  # 2.4 s of video: frames past the CSV's end are dropped
    out = ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))[0]
    demo = read_demonstration(out.output)
    frame_t = t[0] + 40.0 * np.arange(60)
    kept = frame_t[frame_t <= t[-1]]
    assert demo.n_steps == len(kept) < 60
    np.testing.assert_array_equal(demo.timestamps_ns, (kept * 1e6).astype(np.int64))
    pose, grip = motion(kept / 1000)  # linear xyz/gripper and a constant-rate rotation: interpolation is exact
    np.testing.assert_allclose(demo.pose, pose, atol=1e-9)
    np.testing.assert_allclose(demo.gripper, grip, atol=1e-9)
    assert demo.episode.fps == pytest.approx(25.0)
    assert "slerp" in demo.episode.extra["interpolation"]


def test_image_count_mismatch_needs_a_frame_rate(tmp_path):
    src = tmp_path / "demo"
    src.mkdir()
    t = baxter_times(30)
    baxter_csv(src / "pose.csv", t)
    images(src, 5, ".jpg")
    with pytest.raises(RecordingError, match="--frame-rate"):
        ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))
    done = ingest(
        IngestConfig(src=src, out=tmp_path / "out", timing=FrameTiming(frame_rate=20.0, offset_ms=10.0), quiet=True)
    )
    demo = read_demonstration(done[0].output)
    expected_t = t[0] + 10.0 + 50.0 * np.arange(5)
    np.testing.assert_array_equal(demo.timestamps_ns, (expected_t * 1e6).astype(np.int64))
    np.testing.assert_allclose(demo.pose, motion(expected_t / 1000)[0], atol=1e-9)
    assert demo.frames == [p.read_bytes() for p in sorted(src.glob("*.jpg"))]  # JPEG files kept byte for byte


def test_custom_column_mapping(tmp_path):
    path = tmp_path / "log.csv"
    t = np.array([0.0, 0.5, 1.0])
    pose, grip = motion(t)
    lines = ["stamp,x,y,z,rx,ry,rz,rw"] + [",".join(repr(float(v)) for v in [ti, *p]) for ti, p in zip(t, pose)]
    path.write_text("\n".join(lines))
    cols = CsvColumns.from_overrides(
        {
            "time": "stamp",
            "time_unit": "s",
            "x": "x",
            "y": "y",
            "z": "z",
            "qx": "rx",
            "qy": "ry",
            "qz": "rz",
            "qw": "rw",
            "gripper": "",
        }
    )
    demo = read_demonstration(ingest(IngestConfig(src=path, out=tmp_path / "out", columns=cols, quiet=True))[0].output)
    np.testing.assert_array_equal(demo.timestamps_ns, [0, 500_000_000, 1_000_000_000])
    np.testing.assert_allclose(demo.pose, pose)
    np.testing.assert_array_equal(demo.gripper, 0.0)
    with pytest.raises(RecordingError, match="unknown keys"):
        CsvColumns.from_overrides({"colour": "c"})


def test_robot_mcap_with_other_topic_names(tmp_path):
    src = robot_mcap(tmp_path / "robot.mcap")
    topics = McapTopics(image="/robot/camera", pose="/robot/ee", gripper="/robot/joints", gripper_joint="gripper_joint")
    demo = read_demonstration(ingest(IngestConfig(src=src, out=tmp_path / "out", topics=topics, quiet=True))[0].output)
    frame_t = np.arange(11) * 0.1
    assert demo.n_steps == 11
    np.testing.assert_array_equal(demo.timestamps_ns - demo.timestamps_ns[0], np.round(frame_t * 1e9).astype(np.int64))
    pose, grip = motion(frame_t)
    np.testing.assert_allclose(demo.pose, pose, atol=1e-9)
    np.testing.assert_allclose(demo.gripper, grip, atol=1e-9)
    assert len(demo.frames) == 11 and all(f[:2] == b"\xff\xd8" for f in demo.frames)

    motion_only = McapTopics(image="", pose="/robot/ee", gripper="/robot/joints", gripper_joint="gripper_joint")
    demo = read_demonstration(
        ingest(IngestConfig(src=src, out=tmp_path / "out2", topics=motion_only, quiet=True))[0].output
    )
    assert demo.n_steps == 51 and demo.frames is None


def test_ros2_mcap(tmp_path):
    src = ros2_robot_mcap(tmp_path / "ros2.mcap")
    topics = McapTopics(
        image="/cam/compressed", pose="/ee_pose", gripper="/joint_states", gripper_joint="gripper_joint"
    )
    demo = read_demonstration(ingest(IngestConfig(src=src, out=tmp_path / "out", topics=topics, quiet=True))[0].output)
    frame_t = np.arange(11) * 0.1
    np.testing.assert_array_equal(demo.timestamps_ns - demo.timestamps_ns[0], np.round(frame_t * 1e9).astype(np.int64))
    pose, grip = motion(frame_t)
    np.testing.assert_allclose(demo.pose, pose, atol=1e-9)
    np.testing.assert_allclose(demo.gripper, grip, atol=1e-9)
    camera = [v for _, role, v in robot_samples(1.0, 10.0, 50.0, 20.0) if role == "camera"]
    assert demo.frames == [jpeg_of(img) for img in camera]  # JPEG frames kept byte for byte


def test_robot_mcap_missing_topic_names_the_topics(tmp_path):
    src = robot_mcap(tmp_path / "robot.mcap")
    with pytest.raises(RecordingError) as info:
        ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))
    msg = str(info.value)
    assert str(src) in msg and "'/ee/pose'" in msg and "/robot/ee" in msg and "--pose-topic" in msg
    assert not (tmp_path / "out" / "robot.mcap").exists()


@pytest.mark.parametrize(
    "line,column,value,words",
    [
        (4, 3, "nan", "line 4, column 'p_x' is nan"),
        (4, 3, "abc", "line 4, column 'p_x': 'abc' is not a number"),
        (5, 0, "1", "backwards (or repeats) at line 5"),
        (1, 10, "grip", "missing CSV columns (gripper: gripper_position or gripper)"),
    ],
)
def test_bad_csv(tmp_path, line, column, value, words):
    path = baxter_csv(tmp_path / "bad.csv", baxter_times(6))
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][column] = value
    path.write_text("\n".join(",".join(r) for r in rows))
    before = path.read_bytes()
    with pytest.raises(RecordingError) as info:
        ingest(IngestConfig(src=path, out=tmp_path / "out", quiet=True))
    assert str(path) in str(info.value) and words in str(info.value)
    assert path.read_bytes() == before
    assert not list((tmp_path / "out").glob("*.mcap"))


def test_output_inside_source_is_refused(tmp_path):
    baxter_csv(tmp_path / "a.csv", baxter_times(5))
    with pytest.raises(PipelineError, match="the output folder is inside the input"):
        ingest(IngestConfig(src=tmp_path, out=tmp_path / "out", quiet=True))


def test_output_replacing_its_input_is_refused(tmp_path):
    src = robot_mcap(tmp_path / "robot.mcap")
    before = src.read_bytes()
    topics = McapTopics(image="", pose="/robot/ee", gripper="/robot/joints", gripper_joint="gripper_joint")
    with pytest.raises(RecordingError, match="replace its input"):
        ingest(IngestConfig(src=src, out=tmp_path, topics=topics, quiet=True))
    assert src.read_bytes() == before


def test_cli_ingest(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    baxter_csv(src / "a.csv", baxter_times(5))
    assert main(["-q", "ingest", str(src), "--out", str(tmp_path / "out")]) == 0
    assert "ingested 1 demonstration(s)" in capsys.readouterr().out
    assert main(["-q", "ingest", str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such file or folder" in err[0] and "Traceback" not in err[0]


def test_unwritable_output_is_one_clear_error(tmp_path):
    path = baxter_csv(tmp_path / "a.csv", baxter_times(5))
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(PipelineError, match="cannot create the output folder"):
        ingest(IngestConfig(src=path, out=tmp_path / "file" / "out", quiet=True))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 2**32 - 1),
    rows=st.integers(2, 30),
    unit=st.sampled_from(["s", "ms", "us", "ns"]),
    extra_columns=st.integers(0, 3),
)
def test_csv_ingest_property(tmp_path, seed, rows, unit, extra_columns):
    """Any column order, extra columns, time unit and padding: values come back as written."""
    rng = np.random.default_rng(seed)
    scale = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}[unit]
    t_ns = np.cumsum(rng.integers(1_000_000, 50_000_000, size=rows))  # 1-50 ms apart
    quat = rng.normal(size=(rows, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    cols = {"t": t_ns / scale, "px": rng.normal(size=rows), "py": rng.normal(size=rows), "pz": rng.normal(size=rows)}
    cols.update({f"o{k}": quat[:, i] for i, k in enumerate("xyzw")})
    cols["grip"] = rng.uniform(0, 100, size=rows)
    cols.update({f"junk{i}": rng.normal(size=rows) for i in range(extra_columns)})
    names = list(cols)
    order = rng.permutation(len(names))
    header = ",".join(f"__{names[i]}__" if rng.random() < 0.5 else names[i] for i in order)
    body = [",".join(repr(float(cols[names[i]][r])) for i in order) for r in range(rows)]
    path = tmp_path / f"prop_{seed}.csv"
    path.write_text("\n".join([header, *body]) + "\n")
    mapping = {
        "time": "t",
        "time_unit": unit,
        "x": "px",
        "y": "py",
        "z": "pz",
        "qx": "ox",
        "qy": "oy",
        "qz": "oz",
        "qw": "ow",
        "gripper": "grip",
    }
    demo = demonstration_from_csv(path, "prop", CsvColumns.from_overrides(mapping))
    np.testing.assert_allclose(demo.timestamps_ns, t_ns, rtol=0, atol=1)  # float round trip of the time unit
    np.testing.assert_allclose(demo.pose[:, :3], np.stack([cols["px"], cols["py"], cols["pz"]], axis=1), rtol=0, atol=0)
    np.testing.assert_allclose(demo.pose[:, 3:], quat, atol=1e-15)
    np.testing.assert_allclose(demo.gripper, cols["grip"], rtol=0, atol=0)


def test_a_corrupt_jpeg_in_an_image_folder_is_refused_at_ingest(tmp_path):
    src = tmp_path / "demo"
    src.mkdir()
    baxter_csv(src / "pose.csv", baxter_times(12))
    frames = images(src, 12, ".jpg")
    frames[10].write_bytes(b"\xff\xd8" + bytes(60))  # starts like a JPEG, decodes to nothing
    with pytest.raises(RecordingError, match=r"frame_10.jpg: not a decodable JPEG"):
        ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))
    assert not (tmp_path / "out").exists()


def test_check_decodable_names_the_first_bad_frame():
    from cnep.recordings.media import check_decodable

    good = jpeg_of(np.zeros((8, 8, 3), np.uint8))
    check_decodable([good, good], "x.mcap")
    with pytest.raises(RecordingError, match=r"x.mcap: frame 1 \(4 bytes\) is not a decodable JPEG"):
        check_decodable([good, b"\xff\xd8\xff\xe0", good], "x.mcap")


def test_a_one_frame_video_is_blamed_on_the_video(tmp_path):
    src = tmp_path / "demo"
    src.mkdir()
    baxter_csv(src / "pose.csv", baxter_times(20))
    video(src / "cam.avi", 1, fps=25.0)
    with pytest.raises(
        RecordingError, match=r"cam.avi: the video has 1 readable frame; a demonstration needs at least 2"
    ):
        ingest(IngestConfig(src=src, out=tmp_path / "out", quiet=True))


@pytest.mark.parametrize("style", ["excel-bom", "semicolons"])
def test_csv_saved_by_spreadsheets_is_read(tmp_path, style):
    t = baxter_times(8)
    plain = baxter_csv(tmp_path / "plain.csv", t).read_text()
    if style == "excel-bom":
        text = "\ufeff" + plain
    else:  # the European convention: `;` between cells, decimal commas
        text = "\n".join(";".join(cell.replace(".", ",") for cell in line.split(",")) for line in plain.splitlines())
    (tmp_path / "sheet.csv").write_text(text, encoding="utf-8")
    got = demonstration_from_csv(tmp_path / "sheet.csv", "sheet")
    want = demonstration_from_csv(tmp_path / "plain.csv", "plain")
    np.testing.assert_array_equal(got.timestamps_ns, want.timestamps_ns)
    np.testing.assert_allclose(got.pose, want.pose, atol=1e-12)


def test_a_header_and_one_row_says_so(tmp_path):
    lines = baxter_csv(tmp_path / "a.csv", baxter_times(5)).read_text().splitlines()
    (tmp_path / "a.csv").write_text("\n".join(lines[:2]))
    with pytest.raises(RecordingError, match="found a header and 1 data row; a demonstration needs at least 2"):
        demonstration_from_csv(tmp_path / "a.csv", "a")


def test_a_re_run_skips_current_outputs_and_finishes_an_interrupted_one(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    for name in ("a", "b", "c"):
        baxter_csv(src / f"{name}.csv", baxter_times(8))
    out = tmp_path / "out"
    assert main(["-q", "ingest", str(src), "--out", str(out)]) == 0
    written = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    (out / "b.mcap").unlink()  # a run killed before b was renamed into place leaves its temporary file
    (out / f".b.mcap.{dead_pid()}-abcdef.tmp").write_bytes(b"half")
    capsys.readouterr()
    assert main(["-q", "ingest", str(src), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "ingested 1 demonstration(s) into" in printed and "(2 up to date;" in printed
    assert sorted(p.name for p in out.iterdir()) == [
        RECORD_FILE,
        "a.mcap",
        "b.mcap",
        "c.mcap",
    ]  # the temporary file is gone
    assert all((out / n).stat().st_mtime_ns == written[n] for n in ("a.mcap", "c.mcap"))

    # other options make other files: refused without --force
    assert main(["-q", "ingest", str(src), "--out", str(out), "--task", "pour"]) == 2
    assert "is not this source's demonstration file from these options" in capsys.readouterr().err
    # a source edited since: its output is redone
    os.utime(src / "a.csv", ns=(written["a.mcap"] + 10**9,) * 2)
    assert main(["-q", "ingest", str(src), "--out", str(out)]) == 0
    assert (out / "a.mcap").stat().st_mtime_ns != written["a.mcap"]


def test_force_never_replaces_a_file_cnep_did_not_write(tmp_path, capsys):
    baxter_csv(tmp_path / "a.csv", baxter_times(5))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.mcap").write_text("my own notes")
    for force in ([], ["--force"]):
        assert main(["-q", "ingest", str(tmp_path / "a.csv"), "--out", str(tmp_path / "out"), *force]) == 2
        assert (tmp_path / "out" / "a.mcap").read_text() == "my own notes"
    assert "a.mcap: --force replaces only what `cnep ingest` recorded writing" in capsys.readouterr().err
