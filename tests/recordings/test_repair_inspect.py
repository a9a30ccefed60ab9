import numpy as np
import pytest

from cnep.pipeline.cli.main import main
from cnep.recordings import RecordingError, read_demonstration, read_trajectory, write_demonstration, write_trajectory
from cnep.recordings.inspection import format_report, inspect_file
from cnep.recordings.repair import repair
from tests.recordings.factories import demonstration_factory, trajectory_factory


@pytest.fixture(scope="module")
def long_traj():
    return trajectory_factory(steps=700, features=True)  # ~3.6 MB: many chunks


def truncate(path, fraction):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    return path.read_bytes()


@pytest.mark.parametrize("fraction", [0.5, 0.9])
def test_repair_salvages_complete_chunks_of_a_truncated_trajectory(tmp_path, long_traj, fraction):
    src = write_trajectory(tmp_path / "t.mcap", long_traj)
    damaged = truncate(src, fraction)
    report = repair(src, tmp_path / "fixed.mcap")
    assert src.read_bytes() == damaged  # input untouched
    back = read_trajectory(report.dst)
    assert 0 < back.n_steps < long_traj.n_steps and report.steps == back.n_steps
    assert report.chunks_read >= 1 and not report.was_complete and "truncated" in report.problem
    np.testing.assert_array_equal(back.data, long_traj.data[: back.n_steps])  # a prefix, bit for bit
    np.testing.assert_array_equal(back.timestamps_ns, long_traj.timestamps_ns[: back.n_steps])
    assert back.extractor == long_traj.extractor and back.episode == long_traj.episode
    assert f"{back.n_steps} complete steps" in report.summary()
    # more of the file -> at least as many steps
    if fraction == 0.9:
        assert back.n_steps >= long_traj.n_steps * 0.6


def test_repair_keeps_only_steps_whose_feature_views_survived_too(tmp_path):
    traj = trajectory_factory(steps=300)
    traj.views = np.random.default_rng(0).normal(size=(2, 300, 1280)).astype(np.float32)
    src = write_trajectory(tmp_path / "t.mcap", traj)
    truncate(src, 0.5)
    back = read_trajectory(repair(src, tmp_path / "fixed.mcap").dst)
    assert 0 < back.n_steps < traj.n_steps
    np.testing.assert_array_equal(back.data, traj.data[: back.n_steps])
    np.testing.assert_array_equal(back.views, traj.views[:, : back.n_steps])


def test_repair_skips_a_damaged_chunk_in_the_middle(tmp_path, long_traj):
    from tests.recordings.test_bad_input import chunk_offsets

    src = write_trajectory(tmp_path / "t.mcap", long_traj)
    start, length = chunk_offsets(src)[1]
    data = bytearray(src.read_bytes())
    data[start + length // 2] ^= 0xFF
    src.write_bytes(bytes(data))
    report = repair(src, tmp_path / "fixed.mcap")
    assert report.chunks_lost == 1
    back = read_trajectory(report.dst)
    kept = np.isin(long_traj.timestamps_ns, back.timestamps_ns)
    assert 0 < back.n_steps < long_traj.n_steps
    np.testing.assert_array_equal(back.data, long_traj.data[kept])


def test_repair_trims_a_half_written_demonstration_step(tmp_path):
    demo = demonstration_factory(steps=200, frames=True, frame_size=128)  # ~2 MB: two chunks
    src = write_demonstration(tmp_path / "d.mcap", demo)
    truncate(src, 0.7)
    back = read_demonstration(repair(src, tmp_path / "fixed.mcap").dst)
    assert 0 < back.n_steps < 200
    np.testing.assert_array_equal(back.pose, demo.pose[: back.n_steps])
    assert back.frames == demo.frames[: back.n_steps]


@pytest.mark.parametrize("kind", ["demonstration", "trajectory"])  # zstd and lz4 chunks
def test_repair_salvages_the_complete_messages_of_a_single_chunk_cut_in_half(tmp_path, kind, monkeypatch):
    monkeypatch.setattr("cnep.recordings.container.CHUNK_SIZE_BYTES", 1 << 20)  # as other tools write: large chunks
    if kind == "demonstration":
        original = demonstration_factory(steps=60, frames=True, frame_size=96)  # ~0.4 MB: one chunk
        src = write_demonstration(tmp_path / "d.mcap", original)
    else:
        original = trajectory_factory(steps=150, features=True)  # ~0.8 MB: one chunk
        src = write_trajectory(tmp_path / "t.mcap", original)
    truncate(src, 0.5)
    with pytest.raises(RecordingError, match=r"salvages its 0 complete chunk\(s\) and the \d+ complete message"):
        (read_demonstration if kind == "demonstration" else read_trajectory)(src)
    report = repair(src, tmp_path / "fixed.mcap")
    back = (read_demonstration if kind == "demonstration" else read_trajectory)(report.dst)
    assert report.chunks_read == 0 and report.partial_messages > 0 and report.partial_lost_messages > 0
    assert 0.2 * original.n_steps < back.n_steps < original.n_steps and report.steps == back.n_steps
    np.testing.assert_array_equal(back.timestamps_ns, original.timestamps_ns[: back.n_steps])
    if kind == "demonstration":
        np.testing.assert_array_equal(back.pose, original.pose[: back.n_steps])
        assert back.frames == original.frames[: back.n_steps]
    else:
        np.testing.assert_array_equal(back.data, original.data[: back.n_steps])
    assert f"{report.partial_messages} message(s) of the chunk the end of the file cuts" in report.summary()


def test_repair_refuses_what_it_cannot_help(tmp_path, long_traj):
    src = write_trajectory(tmp_path / "t.mcap", long_traj)
    with pytest.raises(RecordingError, match="output is the input"):
        repair(src, src)
    src.write_bytes(src.read_bytes()[:400])  # inside the first block of the first chunk
    with pytest.raises(RecordingError, match="nothing to salvage"):
        repair(src, tmp_path / "fixed.mcap")
    assert not (tmp_path / "fixed.mcap").exists()


def test_inspect_reports_topics_rates_metadata_and_layout(tmp_path):
    traj = trajectory_factory(steps=30, features=False)
    report = inspect_file(write_trajectory(tmp_path / "t.mcap", traj))
    assert report.complete and report.check == "ok"
    (topic,) = report.topics
    assert (topic.topic, topic.schema, topic.count) == ("/trajectory", "cnep.FeatureVector", 30)
    assert topic.rate_hz == pytest.approx(10.0)
    assert report.duration_s == pytest.approx(2.9)
    assert report.blocks["/trajectory"]["gripper"] == [7, 8]
    assert report.metadata["steps"]["n_steps"] == "30"
    text = format_report(report)
    assert "complete: yes" in text and "cnep.FeatureVector" in text and "format_version=1" in text


def test_inspect_a_truncated_file(tmp_path, long_traj):
    src = write_trajectory(tmp_path / "t.mcap", long_traj)
    truncate(src, 0.5)
    report = inspect_file(src)
    assert not report.complete and "truncated" in report.problem and report.check.startswith("refused")
    assert 0 < report.topics[0].count < long_traj.n_steps


def test_cli_inspect_and_repair(tmp_path, capsys, long_traj):
    good = write_trajectory(tmp_path / "good.mcap", trajectory_factory(steps=5, features=False))
    bad = write_trajectory(tmp_path / "bad.mcap", long_traj)
    truncate(bad, 0.6)
    (tmp_path / "empty.mcap").write_bytes(b"")
    assert main(["inspect", str(good)]) == 0
    assert "complete: yes" in capsys.readouterr().out
    assert main(["inspect", str(good), str(bad)]) == 2  # a damaged input: the contract's exit 2
    assert "complete: NO" in capsys.readouterr().out
    assert main(["inspect", str(tmp_path / "empty.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "empty file" in err[0]
    assert main(["repair", str(bad), str(tmp_path / "fixed.mcap")]) == 0
    assert "complete steps" in capsys.readouterr().out
    assert main(["inspect", str(tmp_path / "fixed.mcap")]) == 0
    assert main(["repair", str(tmp_path / "empty.mcap"), str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("cnep repair: error:") and "empty file" in err[-1]


def test_a_motion_only_recording_cut_in_half_loses_only_the_chunk_the_cut_falls_in(tmp_path):
    """Chunks of a bounded size (CHUNK_SIZE_BYTES): a short recording is several chunks, and a file cut anywhere keeps
    every chunk before the cut."""
    from mcap.reader import make_reader

    demo = demonstration_factory(453, frames=False, seed=0)  # motion only: pose and gripper, ~55 kB
    src = write_demonstration(tmp_path / "m.mcap", demo)
    with open(src, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 4  # not one chunk for the whole recording
    half = len(src.read_bytes()) // 2
    (tmp_path / "cut.mcap").write_bytes(src.read_bytes()[:half])
    assert main(["-q", "repair", str(tmp_path / "cut.mcap"), str(tmp_path / "fixed.mcap")]) == 0
    back = read_demonstration(tmp_path / "fixed.mcap")
    before_cut = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= half]  # complete before the cut
    last = max((c.message_end_time for c in before_cut), default=-1)
    steps = int(np.sum(demo.timestamps_ns <= last))  # the steps with a message in a complete chunk
    assert before_cut and back.n_steps >= steps - 1 > 0  # all of them (the last may have its gripper after the cut)
    np.testing.assert_array_equal(back.pose[: back.n_steps], demo.pose[: back.n_steps])
    assert back.n_steps < demo.n_steps
