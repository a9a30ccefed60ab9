import os
from pathlib import Path

import numpy as np
import pytest

from cnep.models.schedule import FEW_DEMONSTRATIONS
from cnep.outputs import RECORD_FILE
from cnep.perception import FeatureExtractor, PerceptionError, decode_image
from cnep.perception.constants import DEFAULT_VIEWS, WEIGHTS_ENV_VAR
from cnep.perception.frames import resize_frames
from cnep.perception.views import Views
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.extract.stage import (
    ExtractConfig,
    calibration_frames,
    extract,
    plan_outputs,
    shard_of,
    views_for,
)
from cnep.pipeline.identity import check_identities, check_same_extractor
from cnep.recordings import read_trajectory, write_demonstration
from tests.recordings.factories import cut_after_header, demonstration_factory


@pytest.fixture
def demos(tmp_path) -> list[Path]:
    """Two demonstration files with 6 frames each, in tmp_path/demos."""
    folder = tmp_path / "demos"
    folder.mkdir()
    return [
        write_demonstration(folder / f"demo-{k}.mcap", demonstration_factory(6, seed=k, episode_id=f"demo-{k}"))
        for k in range(2)
    ]


def _config(inputs, out, **overrides) -> ExtractConfig:
    """The job extracting `inputs` into `out`: random weights, no views unless a test asks for them."""
    settings = {"weights": "random", "backend": "eager", "threads": 1, "quiet": True, "views": 0, **overrides}
    return ExtractConfig(inputs=tuple(inputs), out=out, **settings)


@pytest.mark.slow
def test_trajectories_hold_features_pose_gripper_and_identity(demos, tmp_path):
    done = extract(_config(demos, tmp_path / "out"))
    assert [item.output.name for item in done] == ["demo-0.mcap", "demo-1.mcap"]
    reference = FeatureExtractor("random", backend="eager", threads=1)
    reference.calibrate(calibration_frames(demos, 256))
    for item, demo_path in zip(done, demos):
        traj = read_trajectory(item.output)
        demo = demonstration_factory(6, seed=int(demo_path.stem[-1]))
        assert traj.width == 1288 and traj.features.shape == (6, 1280)
        np.testing.assert_allclose(traj.pose, demo.pose, rtol=1e-6)
        np.testing.assert_allclose(traj.gripper, demo.gripper, rtol=1e-6)
        np.testing.assert_array_equal(traj.timestamps_ns, demo.timestamps_ns)
        expected = reference(np.stack([decode_image(f) for f in demo.frames]))  # (6, 1280)
        np.testing.assert_allclose(traj.features, expected, atol=1e-5)
        assert traj.extractor == reference.identity
        assert traj.frames == demo.frames  # kept for replay
    assert check_same_extractor([item.output for item in done]) == reference.identity


@pytest.mark.slow
def test_calibration_does_not_depend_on_input_order(demos, tmp_path):
    first = extract(_config(demos, tmp_path / "a"))
    second = extract(_config(demos[::-1], tmp_path / "b"))
    assert read_trajectory(first[0].output).extractor == read_trajectory(second[1].output).extractor


@pytest.mark.slow
def test_up_to_date_outputs_are_skipped_and_stale_ones_redone(demos, tmp_path):
    out = tmp_path / "out"
    extract(_config(demos, out))
    stamps = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    again = extract(_config(demos, out))
    assert all(item.skipped for item in again) and [item.n_steps for item in again] == [6, 6]
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == stamps
    later = max(stamps.values()) + 10**9
    os.utime(demos[1], ns=(later, later))  # the input changed after its output was written
    assert [item.skipped for item in extract(_config(demos, out))] == [True, False]
    assert [item.skipped for item in extract(_config(demos, out, force=True))] == [False, False]
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(
        PipelineError,
        match="already exists and is not this input's trajectory file from these weights and views .and 1 more.; "
        "add --force",
    ):
        extract(_config(demos, out, seed=1))  # other weights: their features are not replaced silently
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [item.skipped for item in extract(_config(demos, out, seed=1, force=True))] == [False, False]


def test_corrupt_frame_names_file_and_step_and_leaves_no_output(tmp_path):
    demo = demonstration_factory(6, seed=0)
    demo.frames[3] = cut_after_header(demo.frames[3])  # a JPEG's header, then nothing to decode
    src = write_demonstration(tmp_path / "broken.mcap", demo)
    out = tmp_path / "out"
    with pytest.raises(PerceptionError, match=r"broken\.mcap: step 3 on /camera/rgb: cannot decode image"):
        extract(_config([src], out, weights="random"))
    assert not out.exists()  # the contract: a failed run leaves no empty output folder


def test_corrupt_frame_after_calibration_leaves_other_outputs(demos, tmp_path):
    # weights from a file: no calibration pass, so the corrupt frame is met during extraction itself
    weights = tmp_path / "w.pt"
    extract(_config(demos[:1], tmp_path / "first", save_weights=weights))
    demo = demonstration_factory(6, seed=5)
    demo.frames[5] = cut_after_header(demo.frames[5])
    broken = write_demonstration(tmp_path / "demos" / "z-broken.mcap", demo)
    out = tmp_path / "out"
    with pytest.raises(PerceptionError, match=r"z-broken\.mcap: step 5"):
        extract(_config([*demos, broken], out, weights=str(weights)))
    assert sorted(p.name for p in out.iterdir()) == [RECORD_FILE, "demo-0.mcap", "demo-1.mcap"]


def test_saved_weights_reproduce_the_features(demos, tmp_path):
    weights = tmp_path / "calibrated.pt"
    first = extract(_config(demos, tmp_path / "a", save_weights=weights))
    second = extract(_config(demos[1:], tmp_path / "b", weights=str(weights)))
    a, b = read_trajectory(first[1].output), read_trajectory(second[0].output)
    np.testing.assert_array_equal(a.features, b.features)
    check_same_extractor([first[0].output, second[0].output])  # same weights hash: may be mixed


def test_motion_only_demonstration_gives_motion_only_trajectory(tmp_path):
    src = write_demonstration(tmp_path / "motion.mcap", demonstration_factory(5, frames=False))
    done = extract(_config([src], tmp_path / "out", weights="imagenet"))  # no frames: no weights needed
    assert read_trajectory(done[0].output).width == 8
    assert extract(_config([src], tmp_path / "out", weights="imagenet"))[0].skipped


@pytest.mark.slow
def test_mixing_extractors_is_refused_naming_the_odd_files(demos, tmp_path):
    a = extract(_config(demos, tmp_path / "a"))
    b = extract(_config(demos[:1], tmp_path / "b", seed=1))
    with pytest.raises(PipelineError) as info:
        check_same_extractor([a[0].output, a[1].output, b[0].output])
    message = str(info.value)
    assert "different feature extractors" in message
    assert "1 file(s) with weights random:seed=1" in message and str(b[0].output) in message
    assert "2 file(s) with weights random:seed=0" in message


def test_backend_alone_does_not_prevent_mixing():
    identity = {
        "architecture": "a",
        "feature_dim": "1280",
        "weights": "w",
        "weights_sha256": "0" * 64,
        "preprocessing": "p",
        "backend": "eager",
    }
    shared = check_identities({Path("x"): identity, Path("y"): {**identity, "backend": "onnxruntime"}})
    assert shared == identity
    with pytest.raises(PipelineError, match="without features \\(motion-only\\): z"):
        check_identities({Path("x"): identity, Path("y"): identity, Path("z"): {}})


def test_outputs_never_overwrite_inputs(demos, tmp_path):
    with pytest.raises(PipelineError, match="would overwrite this input"):
        plan_outputs(demos, demos[0].parent)
    with pytest.raises(PipelineError, match="no such file or folder"):
        plan_outputs([tmp_path / "missing.mcap"], tmp_path / "out")
    other = tmp_path / "other"
    other.mkdir()
    clash = write_demonstration(other / "demo-0.mcap", demonstration_factory(3))
    with pytest.raises(PipelineError, match="would both be written to"):
        plan_outputs([demos[0], clash], tmp_path / "out")


def test_folder_inputs_keep_relative_paths(tmp_path):
    nested = tmp_path / "in" / "day1"
    nested.mkdir(parents=True)
    write_demonstration(nested / "a.mcap", demonstration_factory(3))
    assert plan_outputs([tmp_path / "in"], tmp_path / "out") == [(nested / "a.mcap", tmp_path / "out/day1/a.mcap")]


def test_cli_extracts_and_reports(demos, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "-q",
            "extract",
            str(demos[0].parent),
            "--out",
            str(out),
            "--weights",
            "random",
            "--backend",
            "eager",
            "--threads",
            "1",
        ]
    )
    assert code == 0
    assert "extracted 2 trajectory file(s)" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [RECORD_FILE, "demo-0.mcap", "demo-1.mcap"]


def test_cli_without_imagenet_weights_is_a_one_line_error(demos, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv(WEIGHTS_ENV_VAR, raising=False)
    assert main(["-q", "extract", str(demos[0]), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cnep extract: error: ImageNet weights for MobileNet-v2 not found") and "\n" not in err


def test_nested_input_folders_are_extracted_into_matching_sub_folders(tmp_path):
    nested = tmp_path / "in" / "day1"
    nested.mkdir(parents=True)
    write_demonstration(nested / "a.mcap", demonstration_factory(4, frames=False))
    done = extract(_config([tmp_path / "in"], tmp_path / "out", weights="imagenet"))  # motion-only: no weights
    assert done[0].output == tmp_path / "out" / "day1" / "a.mcap"
    assert read_trajectory(done[0].output).n_steps == 4


@pytest.mark.slow  # two spawned processes import torch: ~15 s on 2 idle cores
@pytest.mark.slow
def test_views_are_the_features_of_each_view_of_the_frames_beside_the_demonstration_s_own(demos, tmp_path):
    done = extract(_config(demos, tmp_path / "out", views=2, workers=2))
    reference = FeatureExtractor("random", backend="eager", threads=1)
    reference.calibrate(calibration_frames(demos, 256))
    for item, demo_path in zip(done, demos):
        traj = read_trajectory(item.output)
        assert traj.views.shape == (2, 6, 1280)
        pixels = resize_frames(np.stack([decode_image(f) for f in traj.frames]))
        np.testing.assert_allclose(traj.features, reference(pixels), atol=1e-4)  # its own, unchanged
        for view, features in zip(Views(2, seed=0).of(demo_path.stem), traj.views):
            np.testing.assert_allclose(features, reference(view.apply(pixels, 0)), atol=1e-4)
        assert not np.allclose(traj.views[0], traj.views[1], atol=1e-3)
    again = extract(_config(demos, tmp_path / "out", views=2))
    assert all(item.skipped for item in again)
    before = {p.name: p.read_bytes() for p in (tmp_path / "out").glob("*.mcap")}
    with pytest.raises(PipelineError, match="is not this input's trajectory file from these weights and views"):
        extract(_config(demos, tmp_path / "out", views=0))  # the files holding views are not replaced silently
    assert {p.name: p.read_bytes() for p in (tmp_path / "out").glob("*.mcap")} == before


def test_a_few_demonstrations_get_the_default_views_and_many_none(monkeypatch, demos, tmp_path):
    assert views_for(FEW_DEMONSTRATIONS - 1) == DEFAULT_VIEWS > 0 and views_for(FEW_DEMONSTRATIONS) == 0
    monkeypatch.setattr("cnep.pipeline.extract.stage.DEFAULT_VIEWS", 1)  # one view: a quicker extraction
    done = extract(_config(demos, tmp_path / "out", views=None))  # the rule's
    assert [read_trajectory(item.output).views.shape for item in done] == [(1, 6, 1280)] * 2


def test_two_worker_processes_give_the_same_files_as_one(demos, tmp_path):
    one = extract(_config(demos, tmp_path / "one"))
    two = extract(_config(demos, tmp_path / "two", workers=2))
    assert [item.output.name for item in two] == ["demo-0.mcap", "demo-1.mcap"]
    assert [(item.n_steps, item.skipped) for item in two] == [(6, False), (6, False)]
    for a, b in zip(one, two):
        first, second = read_trajectory(a.output), read_trajectory(b.output)
        assert second.extractor == first.extractor
        np.testing.assert_array_equal(second.features, first.features)


@pytest.mark.slow
def test_torchrun_ranks_extract_disjoint_shares_with_one_identity(demos, tmp_path, monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    outputs = {}
    for rank in (0, 1):
        monkeypatch.setenv("RANK", str(rank))
        outputs[rank] = extract(_config(demos, tmp_path / "out"))
    assert [item.source for item in outputs[0]] == [demos[0]]
    assert [item.source for item in outputs[1]] == [demos[1]]
    assert check_same_extractor(sorted((tmp_path / "out").glob("*.mcap")))  # both ranks calibrated alike


@pytest.mark.slow
def test_two_shards_write_the_files_of_one_unsharded_run_byte_for_byte(tmp_path, monkeypatch):
    monkeypatch.setattr("cnep.pipeline.extract.stage.DEFAULT_VIEWS", 1)  # one view: a quicker extraction
    folder = tmp_path / "demos"
    folder.mkdir()
    demos = [
        write_demonstration(folder / f"demo-{k}.mcap", demonstration_factory(4, seed=k, episode_id=f"demo-{k}"))
        for k in range(5)
    ]
    whole = extract(_config(demos, tmp_path / "whole", views=None))  # the rule's views, from every input's count
    shards = [
        main(["-q", "extract", str(folder), "--out", str(tmp_path / "sharded"), "--weights", "random",
              "--backend", "eager", "--threads", "1", "--shard", f"{i}/2"])
        for i in (0, 1)
    ]  # fmt: skip
    assert shards == [0, 0]
    written = sorted(p.name for p in (tmp_path / "sharded").glob("*.mcap"))
    assert written == [item.output.name for item in whole]
    for item in whole:
        assert (tmp_path / "sharded" / item.output.name).read_bytes() == item.output.read_bytes()


def test_shards_are_disjoint_cover_the_inputs_and_ignore_their_order(tmp_path):
    pairs = [(tmp_path / f"in-{k}.mcap", tmp_path / "out" / f"{k:02d}.mcap") for k in range(7)]
    shards = [shard_of(pairs, i, 3) for i in range(3)]
    assert sorted(pair for part in shards for pair in part) == sorted(pairs)
    assert [len(part) for part in shards] == [3, 2, 2]
    assert [sorted(shard_of(pairs[::-1], i, 3)) for i in range(3)] == [sorted(part) for part in shards]


@pytest.mark.parametrize("shard", ["2/2", "-1/2", "1", "a/b"])
def test_a_shard_outside_its_count_is_refused(demos, tmp_path, shard, capsys):
    with pytest.raises(SystemExit) as stopped:  # argparse's one line, exit 2
        main(["extract", str(demos[0]), "--out", str(tmp_path / "out"), f"--shard={shard}"])
    assert stopped.value.code == 2 and "--shard" in capsys.readouterr().err


def test_calibration_reads_only_the_files_it_samples_from(demos, tmp_path, monkeypatch):
    from cnep.pipeline.extract import stage

    read = []
    original = stage.read_demonstration
    monkeypatch.setattr(stage, "read_demonstration", lambda path: read.append(path) or original(path))
    frames = calibration_frames(demos, 3)  # 2 from the first file, 1 from the second: both are read, one at a time
    assert frames.shape == (3, 224, 224, 3) and read == sorted(demos)
    read.clear()
    assert calibration_frames(demos, 1).shape == (1, 224, 224, 3) and read == [sorted(demos)[0]]


def test_workers_must_be_positive(demos, tmp_path):
    with pytest.raises(PipelineError, match="--workers must be >= 1, got 0"):
        _config(demos, tmp_path / "out", workers=0)


def test_auto_workers_start_processes_only_for_jobs_that_pay(demos, tmp_path, monkeypatch):
    from cnep.pipeline.extract import stage

    monkeypatch.setattr(stage, "cpu_cores", lambda: 2)
    assert stage.auto_workers(demos) == 1  # 12 frames: far below WORKER_MIN_FRAMES, no process is started
    monkeypatch.setattr(stage, "WORKER_MIN_FRAMES", 6)
    assert stage.auto_workers(demos) == 2  # 12 frames, 2 files, 2 cores
    assert stage.auto_workers(demos[:1]) == 1  # one file: one process
    monkeypatch.setattr(stage, "cpu_cores", lambda: 1)
    assert stage.auto_workers(demos) == 1


@pytest.mark.slow
def test_cli_workers_auto_extracts_a_small_job_in_this_process(demos, tmp_path, capsys, monkeypatch):
    from cnep.pipeline.extract import stage

    monkeypatch.setattr(stage, "extract_in_processes", lambda *a: pytest.fail("started worker processes"))
    assert (
        main(
            [
                "-q",
                "extract",
                *map(str, demos),
                "--out",
                str(tmp_path / "out"),
                "--weights",
                "random",
                "--backend",
                "eager",
                "--threads",
                "1",
                "--workers",
                "auto",
            ]
        )
        == 0
    )
    assert "extracted 2 trajectory file(s)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["extract", str(demos[0]), "--out", str(tmp_path / "x"), "--workers", "two"])
    assert "expected a whole number or `auto`, got 'two'" in capsys.readouterr().err


@pytest.mark.slow
def test_calibrate_on_gives_later_runs_the_first_runs_identity(demos, tmp_path):
    both = extract(_config(demos, tmp_path / "both"))
    later = extract(_config(demos[1:], tmp_path / "later", calibrate_on=(demos[0].parent,)))
    alone = extract(_config(demos[1:], tmp_path / "alone"))
    reference = read_trajectory(both[1].output)
    assert read_trajectory(later[0].output).extractor == reference.extractor  # calibrated on both files' frames
    np.testing.assert_array_equal(read_trajectory(later[0].output).features, reference.features)
    assert read_trajectory(alone[0].output).extractor["weights_sha256"] != reference.extractor["weights_sha256"]


@pytest.mark.slow  # quantising MobileNet-v2 takes ~10 s (cached afterwards)
@pytest.mark.skipif(
    "onnxruntime" not in __import__("cnep.perception", fromlist=["_"]).available_backends(),
    reason="needs the onnx extra",
)
def test_int8_features_are_close_to_fp32_and_never_mixed_with_them(demos, tmp_path):
    fp32 = extract(_config(demos, tmp_path / "fp32", backend="onnxruntime"))
    int8 = extract(_config(demos, tmp_path / "int8", backend="onnxruntime", precision="int8"))
    a, b = read_trajectory(fp32[0].output), read_trajectory(int8[0].output)
    assert b.extractor["precision"] == "int8" and "sha256=" in b.extractor["quantisation"]
    assert "precision" not in a.extractor  # fp32 files keep the identity they always had
    cosine = (a.features * b.features).sum(1) / np.linalg.norm(a.features, axis=1) / np.linalg.norm(b.features, axis=1)
    assert cosine.min() > 0.99, cosine.min()
    assert not np.array_equal(a.features, b.features)
    with pytest.raises(PipelineError, match="different feature extractors"):
        check_same_extractor([fp32[0].output, int8[1].output])
    again = extract(_config(demos, tmp_path / "int8", backend="onnxruntime", precision="int8"))
    assert all(item.skipped for item in again)  # same frames, same quantisation: up to date
    with pytest.raises(PipelineError, match="not this input's trajectory file from these weights"):
        extract(_config(demos, tmp_path / "int8", backend="onnxruntime"))  # fp32 over int8 outputs: the contract
    fp32_over = extract(_config(demos, tmp_path / "int8", backend="onnxruntime", force=True))
    assert not any(item.skipped for item in fp32_over)
