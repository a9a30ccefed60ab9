import hashlib
import json
import signal
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from cnep.models import CNEPConfig, TrainConfig, Trainer, load_checkpoint, read_checkpoint_config
from cnep.models.assignments import ASSIGNMENTS
from cnep.models.sampler import TrajectoryStack
from cnep.models.train import LEARNED_RATIO, build_model
from cnep.outputs import RECORD_FILE
from cnep.pipeline.cli.main import main
from cnep.pipeline.contract import Terminated
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.constants import LOG_FILE, STATE_FILE
from cnep.pipeline.train.parallel import rank_seed
from cnep.pipeline.train.presets import resolve_preset
from cnep.pipeline.train.stage import StageTrainer, TrainStageConfig, train
from cnep.pipeline.train.state import work_dir
from cnep.recordings import Trajectory, read_trajectory, write_trajectory
from tests.recordings.factories import trajectory_factory

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models run on one thread

LENGTHS = (20, 27, 33, 40, 24)  # demonstrations of different lengths
TINY = {"encoder_widths": (16, 16), "expert_widths": (16, 16), "time_frequencies": 2}


def write_set(folder: Path, features: bool = True, extractor: dict | None = None) -> list[Path]:
    """Trajectory files of LENGTHS steps (seeded random features, pose, gripper) in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, steps in enumerate(LENGTHS):
        traj = trajectory_factory(steps, features=features, seed=k)
        if extractor is not None:
            traj = Trajectory(
                episode=traj.episode, timestamps_ns=traj.timestamps_ns, data=traj.data, extractor=extractor
            )
        paths.append(write_trajectory(folder / f"demo-{k}.mcap", traj))
    return paths


@pytest.fixture
def full_set(tmp_path) -> list[Path]:
    return write_set(tmp_path / "full")


def stage_config(
    inputs, out, steps=30, assignment="bounded", feature_components: int | None = 0, **overrides
) -> TrainStageConfig:
    """A tiny model's training job. Its encoder reads every feature (`feature_components` 0) unless a test asks for
    the rule (None): the projection's fit, an eigendecomposition of the features' correlation matrix, is work the
    stage's mechanics never need."""
    training = TrainConfig(steps=steps, batch_size=8, warmup_steps=5, val_every=10, patience=None, seed=3)
    model = CNEPConfig(assignment=assignment, feature_components=feature_components, **TINY)
    return TrainStageConfig(
        inputs=tuple(inputs), out=out, model=model, training=training, save_every=10, quiet=True, **overrides
    )


def test_cli_trains_a_checkpoint_that_loads_and_generates(full_set, tmp_path, capsys):
    out = tmp_path / "ckpt"
    code = main(
        [
            "-q",
            "train",
            str(full_set[0].parent),
            "--out",
            str(out),
            "--steps",
            "30",
            "--val-every",
            "10",
            "--warmup-steps",
            "5",
            "--batch-size",
            "8",
            "--encoder-widths",
            "16,16",
            "--expert-widths",
            "16,16",
            "--seed",
            "3",
        ]
    )
    assert code == 0 and "best validation error" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == sorted([RECORD_FILE, "config.json", LOG_FILE, "model.safetensors"])
    assert not work_dir(out).exists()
    config = read_checkpoint_config(out)
    assert config["layout"]["name"] == "scene" and config["layout"]["columns"] == [[0, 1288]]  # the default
    assert config["extractor"] == read_trajectory(full_set[0]).extractor
    assert config["training"]["steps"] == 30 and config["training"]["seed"] == 3
    assert [f["sha256"] for f in config["files"]] == [hashlib.sha256(p.read_bytes()).hexdigest() for p in full_set]
    assert [f["n_steps"] for f in config["files"]] == list(LENGTHS)
    assert sorted(f["split"] for f in config["files"]) == ["train"] * 4 + ["validation"]
    log = [json.loads(line) for line in (out / LOG_FILE).read_text().splitlines()]
    assert [entry["step"] for entry in log] == [10, 20, 30]
    assert {"loss", "rec", "batch_entropy", "ind_entropy", "usage", "val_error"} <= set(log[0])
    assert config["model"]["assignment"] == "bounded" and config["training"]["gate_lr_scale"] == 1.0  # the defaults
    settled = [
        e for e in log if e["step"] >= ASSIGNMENTS["bounded"].settled_fraction * 30
    ]  # the best model is kept from there
    best = min(settled, key=lambda e: e["val_error"])
    assert config["result"]["best_step"] == best["step"] and config["result"]["best_val_error"] == best["val_error"]

    model = load_checkpoint(out)
    traj = read_trajectory(full_set[1])
    prediction = model.generate(np.array([0.0, 0.5]), traj.data[[0, 13]], np.linspace(0, 1, 5))  # scene: t only
    assert prediction.mean.shape == (5, 8) and np.isfinite(prediction.mean).all()


def test_feature_components_from_the_command_line_reach_the_checkpoint_fitted_on_the_training_files(
    full_set, tmp_path, capsys
):
    out = tmp_path / "ckpt"
    args = ["-q", "train", str(full_set[0].parent), "--out", str(out), "--steps", "10", "--val-every", "5"]
    args += ["--warmup-steps", "2", "--batch-size", "4", "--encoder-widths", "16,16", "--expert-widths", "16,16"]
    assert main([*args, "--feature-components", "4"]) == 0
    config = read_checkpoint_config(out)
    assert config["model"]["feature_components"] == 4
    model = load_checkpoint(out)
    assert model.encoder[0].weight.shape[1] == 1 + 2 * 8 + 8 + 4  # t and its features, pose and gripper, components
    train = [read_trajectory(f["path"]).data for f in config["files"] if f["split"] == "train"]
    expected = build_model(model.config, train, seed=0)  # from the trajectories; the stage sums per-file moments
    torch.testing.assert_close(model.feature_projection, expected.feature_projection, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(model.normaliser.scale, expected.normaliser.scale, rtol=1e-6, atol=0)
    capsys.readouterr()
    for components, says in (("1281", "at most the 1280 columns"), ("-1", "a whole number >= 0")):
        assert main([*args, "--force", "--feature-components", components]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert main([*args, "--force", "--layout", "motion", "--feature-components", "2"]) == 2
    assert "predicts every column it observes" in capsys.readouterr().err
    assert read_checkpoint_config(out) == config  # refused before anything was replaced


def test_released_weights_are_the_best_validated(full_set, tmp_path):
    out = train(stage_config(full_set, tmp_path / "ckpt", steps=40))
    config = read_checkpoint_config(out)
    model = load_checkpoint(out)
    layout = resolve_preset("wine-glass", 1288, full_set[0])
    rows = {f["path"]: layout.select(read_trajectory(f["path"]).data) for f in config["files"]}
    split = {s: [f for f in config["files"] if f["split"] == s] for s in ("train", "validation")}
    stacks = {  # each file as trained: held at its last step as config.json says (pipeline.train.hold)
        s: TrajectoryStack([rows[f["path"]] for f in files], model, [f.get("held_steps", 0) for f in files])
        for s, files in split.items()
    }
    again = Trainer(
        model,
        stacks["train"],
        stacks["validation"],
        TrainConfig(**{k: v for k, v in config["training"].items() if k in TrainConfig.__annotations__}),
    )
    assert again.validate() == pytest.approx(config["result"]["best_val_error"], rel=1e-6)


def test_layout_presets_map_blocks_to_columns(full_set):
    wine = resolve_preset("wine-glass", 1288, full_set[0])
    assert (wine.roles.observed, wine.roles.query, wine.roles.predicted) == (
        ((0, 1288),),
        ((0, 1280),),
        ((1280, 1288),),
    )
    motion_full, motion_only = resolve_preset("motion", 1288, full_set[0]), resolve_preset("motion", 8, full_set[0])
    assert motion_full.columns == ((1280, 1288),) and motion_only.columns == ((0, 8),)
    assert motion_full.roles == motion_only.roles and motion_full.roles.width == 8 and motion_full.roles.query_dim == 0
    data = read_trajectory(full_set[0]).data
    np.testing.assert_array_equal(motion_full.select(data), data[:, 1280:])
    everything = resolve_preset("all", 1288, full_set[0])
    assert everything.roles.out_dim == 1288 and everything.roles.query == ()


def test_wine_glass_refuses_motion_only_files(tmp_path):
    paths = write_set(tmp_path / "motion", features=False)
    with pytest.raises(PipelineError, match=r"demo-0\.mcap.*--layout motion"):
        train(stage_config(paths, tmp_path / "ckpt"))
    assert not (tmp_path / "ckpt").exists() and not work_dir(tmp_path / "ckpt").exists()


def test_motion_layout_on_motion_only_files(tmp_path):
    paths = write_set(tmp_path / "motion", features=False)
    out = train(stage_config(paths, tmp_path / "ckpt", steps=10, layout="motion"))
    config = read_checkpoint_config(out)
    assert config["model"]["columns"]["width"] == 8 and config["extractor"] == {}
    prediction = load_checkpoint(out).generate(np.array([0.0]), read_trajectory(paths[0]).data[:1], np.array([1.0]))
    assert prediction.mean.shape == (1, 8)


def test_mixed_layouts_are_refused_naming_the_files(full_set, tmp_path):
    odd = write_set(tmp_path / "motion", features=False)[0]
    with pytest.raises(PipelineError, match=r"different column layouts.*1 file\(s\) 8 columns wide: \S*motion/demo-0"):
        train(stage_config([*full_set, odd], tmp_path / "ckpt", layout="motion"))


def test_mixed_extractors_are_refused_naming_the_files(full_set, tmp_path):
    other = {"architecture": "mobilenet_v2", "weights": "random", "weights_sha256": "1" * 64}
    odd = write_set(tmp_path / "other", extractor=other)[:2]
    with pytest.raises(
        PipelineError,
        match=r"different feature extractors.*2 file\(s\) with weights random "
        r"\(sha256 111111111111\).*other/demo-0\.mcap, \S*other/demo-1\.mcap",
    ):
        train(stage_config([*full_set, *odd], tmp_path / "ckpt"))


def test_existing_output_is_refused_unless_forced(full_set, tmp_path):
    out = tmp_path / "ckpt"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(PipelineError, match="already exists.*--force"):
        train(stage_config(full_set, out, steps=10))
    with pytest.raises(
        PipelineError,
        match="keep.txt: --force replaces the folder .* only when `cnep train` recorded writing every file in it",
    ):
        train(stage_config(full_set, out, steps=10, force=True))  # a folder of the user's own files is never deleted
    assert (out / "keep.txt").read_text() == "mine" and not work_dir(out).exists()
    (out / "keep.txt").unlink()
    train(stage_config(full_set, out, steps=10, force=True))  # an empty folder: nothing to lose
    before = (out / "config.json").read_bytes()
    train(stage_config(full_set, out, steps=12, force=True))  # a checkpoint it wrote is replaced
    assert sorted(p.name for p in out.iterdir()) == sorted([RECORD_FILE, "config.json", LOG_FILE, "model.safetensors"])
    assert (out / "config.json").read_bytes() != before and not any(p.name.startswith(".") for p in tmp_path.iterdir())


def interrupt_at(monkeypatch, step: int) -> None:
    """Make training raise KeyboardInterrupt (as Ctrl-C would) when it reaches `step`."""
    original = StageTrainer.train_step

    def train_step(self):
        if self.step == step:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(StageTrainer, "train_step", train_step)


def test_views_of_the_training_files_are_trained_on_and_count_as_scenes_for_the_projection(tmp_path):
    folder = tmp_path / "viewed"
    folder.mkdir()
    for k, steps in enumerate(LENGTHS):
        traj = trajectory_factory(steps, seed=k)
        traj.views = np.random.default_rng(k).normal(size=(2, steps, 1280)).astype(np.float32)
        write_trajectory(folder / f"demo-{k}.mcap", traj)
    out = train(stage_config([folder], tmp_path / "ckpt", steps=10, feature_components=None))
    config = read_checkpoint_config(out)
    fitted = [f for f in config["files"] if f["split"] == "train"]
    assert [f["views"] for f in config["files"]] == [2] * len(LENGTHS)
    assert config["model"]["feature_components"] == 3 * len(fitted)  # each training file and its 2 views
    schedule = config["training"]["schedule"]  # the record says what the model reads, from what
    assert (schedule["inputs"]["scenes"], schedule["feature_components"]) == (3 * len(fitted), 3 * len(fitted))
    assert "feature_components" not in schedule["given"]  # the rule's, not given
    seen = []
    for f in fitted:
        traj = read_trajectory(f["path"])
        seen += [traj.data] + [np.concatenate([view, traj.data[:, 1280:]], axis=1) for view in traj.views]
    model = load_checkpoint(out)
    expected = build_model(model.config, seen, seed=0)  # the normaliser and the projection fitted on every view
    torch.testing.assert_close(model.feature_projection, expected.feature_projection, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(model.normaliser.loc, expected.normaliser.loc, rtol=1e-5, atol=1e-5)


@pytest.mark.slow
def test_resume_after_interruption_gives_the_same_weights(full_set, tmp_path, monkeypatch):
    rule = {"steps": 40, "feature_components": None}  # the projection the rule fits, refitted on resume
    whole = train(stage_config(full_set, tmp_path / "whole", **rule))
    assert read_checkpoint_config(whole)["model"]["feature_components"] == len(LENGTHS) - 1  # one held out
    out = tmp_path / "resumed"
    with monkeypatch.context() as patch:
        interrupt_at(patch, 25)  # the last save was at step 20
        with pytest.raises(KeyboardInterrupt):
            train(stage_config(full_set, out, **rule))
    assert not out.exists() and (work_dir(out) / STATE_FILE).is_file()
    assert [json.loads(line)["step"] for line in (work_dir(out) / LOG_FILE).read_text().splitlines()] == [10, 20]
    with pytest.raises(PipelineError, match="unfinished run.*--resume"):
        train(stage_config(full_set, out, **rule))
    resume = stage_config(full_set, out, resume=True, **rule)
    with pytest.raises(PipelineError, match=r"cannot resume.*training: saved .*\"lr\": 0.001"):
        train(replace(resume, training=replace(resume.training, lr=0.01)))

    train(resume)
    expected, got = load_file(whole / "model.safetensors"), load_file(out / "model.safetensors")
    assert expected.keys() == got.keys()
    for key in expected:
        assert torch.equal(expected[key], got[key]), key
    logs = [
        [
            {k: v for k, v in json.loads(line).items() if k != "elapsed_s"}
            for line in (d / LOG_FILE).read_text().splitlines()
        ]
        for d in (whole, out)
    ]
    assert logs[0] == logs[1]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_saves_the_step_it_arrived_in_and_resume_loses_nothing(full_set, tmp_path, monkeypatch, signum):
    """A polite kill (preemption) in the middle of step 26: the run ends after that step, saving its state, and the
    resumed run reaches the weights of an uninterrupted one."""
    whole = train(stage_config(full_set, tmp_path / "whole", steps=40))
    out = tmp_path / "resumed"
    original = StageTrainer.train_step

    def train_step(self):
        if self.step == 25:
            signal.raise_signal(signum)  # delivered to this thread while the step runs
        return original(self)

    with monkeypatch.context() as patch:
        patch.setattr(StageTrainer, "train_step", train_step)
        with pytest.raises(Terminated if signum == signal.SIGTERM else KeyboardInterrupt):
            train(stage_config(full_set, out, steps=40))
    assert torch.load(work_dir(out) / STATE_FILE, weights_only=True)["trainer"]["step"] == 26
    train(stage_config(full_set, out, steps=40, resume=True))
    expected, got = load_file(whole / "model.safetensors"), load_file(out / "model.safetensors")
    assert all(torch.equal(expected[key], got[key]) for key in expected)


def test_training_that_diverges_stops_with_one_line_and_leaves_nothing(full_set, tmp_path, capsys):
    code = main(
        ["-q", "train", *map(str, full_set), "--out", str(tmp_path / "ckpt"), "--layout", "motion"]
        + ["--steps", "40", "--val-every", "10", "--lr", "1e8", "--encoder-widths", "8", "--expert-widths", "8"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "training diverged before any weights could be kept (at step 10" in err[0] and "lower --lr" in err[0]
    assert [p.name for p in tmp_path.iterdir()] == ["full"]  # the inputs only


def test_training_that_diverges_late_keeps_the_best_weights_and_warns(full_set, tmp_path, monkeypatch, caplog):
    original = StageTrainer.validate
    monkeypatch.setattr(StageTrainer, "validate", lambda self: float("nan") if self.step == 30 else original(self))
    config = stage_config(full_set, tmp_path / "ckpt", steps=40, assignment="paper")  # keeps the best from step 0
    with caplog.at_level("WARNING"):
        out = train(config)
    assert "training diverged (at step 30 the training loss is" in caplog.text
    result = read_checkpoint_config(out)["result"]
    assert result["best_step"] == 20 and result["steps_run"] == 30 and result["stopped_early"]


def test_resume_without_a_run_is_refused(full_set, tmp_path):
    with pytest.raises(PipelineError, match="nothing to resume"):
        train(stage_config(full_set, tmp_path / "ckpt", resume=True))


@pytest.mark.slow
def test_early_stopping_ends_the_run(full_set, tmp_path):
    # patience counts from where the posterior settles (Assignment.settled_fraction): 200 steps stop at 170
    config = stage_config(full_set, tmp_path / "ckpt", steps=200)
    out = train(replace(config, training=replace(config.training, patience=1, lr=0.05)))
    result = read_checkpoint_config(out)["result"]
    assert result["stopped_early"] and result["steps_run"] < 200


def test_rank_seeds_differ_and_rank_zero_keeps_the_seed():
    assert rank_seed(7, 0) == 7
    assert len({rank_seed(7, r) for r in range(8)}) == 8


def test_unknown_device_is_refused(full_set, tmp_path):
    with pytest.raises(PipelineError, match="unknown device 'tpu'"):
        train(stage_config(full_set, tmp_path / "ckpt", device="tpu"))


def test_settings_precedence_is_defaults_then_config_file_then_command_line(full_set, tmp_path):
    settings = tmp_path / "settings.json"
    settings.write_text(
        json.dumps(
            {"steps": 10, "seed": 5, "layout": "motion", "encoder_widths": [8, 8], "expert_widths": [8, 8], "lr": 0.002}
        )
    )
    out = tmp_path / "ckpt"
    assert (
        main(
            [
                "-q",
                "train",
                *map(str, full_set),
                "--out",
                str(out),
                "--config",
                str(settings),
                "--seed",
                "7",
                "--val-every",
                "5",
                "--assignment",
                "mixture",
            ]
        )
        == 0
    )
    config = read_checkpoint_config(out)
    training = config["training"]
    assert (training["steps"], training["lr"], config["layout"]["name"]) == (10, 0.002, "motion")  # file
    assert (training["seed"], training["val_every"]) == (7, 5)  # command line over file and defaults
    assert training["patience"] == 10 and training["batch_size"] == TrainConfig().batch_size  # defaults
    # the schedule fills the warm-up from the steps given, and says from what and which values were given
    assert training["warmup_steps"] == 5 and training["schedule"]["given"] == ["steps", "val_every"]
    trained = sum(f["split"] == "train" for f in config["files"])
    inputs = {"demonstrations": trained, "batch_size": training["batch_size"], "scenes": trained}  # no views
    assert training["schedule"]["inputs"] == inputs
    assert config["model"]["encoder_widths"] == [8, 8] and config["model"]["n_experts"] == 2
    assert config["model"]["assignment"] == "mixture"  # the loss's assignment travels with the checkpoint


def test_bad_config_file_is_one_clear_error(full_set, tmp_path, capsys):
    settings = tmp_path / "settings.json"
    settings.write_text(json.dumps({"steps": "many", "colour": "red"}))
    assert main(["train", *map(str, full_set), "--out", str(tmp_path / "ckpt"), "--config", str(settings)]) == 2
    assert "settings.json: unknown setting(s) colour" in capsys.readouterr().err
    settings.write_text(json.dumps({"steps": "many"}))
    assert main(["train", *map(str, full_set), "--out", str(tmp_path / "ckpt"), "--config", str(settings)]) == 2
    assert (
        "setting steps must be an integer from -9223372036854775807 to 9223372036854775807, got 'many'"
        in capsys.readouterr().err
    )


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_training_is_seeded_and_its_checkpoint_runs_on_the_cpu(full_set, tmp_path):
    args = [
        "-q",
        "train",
        str(full_set[0].parent),
        "--steps",
        "30",
        "--val-every",
        "10",
        "--warmup-steps",
        "5",
        "--batch-size",
        "8",
        "--encoder-widths",
        "16,16",
        "--expert-widths",
        "16,16",
        "--seed",
        "3",
        "--device",
        "cuda",
    ]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0 and main(args + ["--out", str(tmp_path / "b")]) == 0
    first, second = load_file(tmp_path / "a" / "model.safetensors"), load_file(tmp_path / "b" / "model.safetensors")
    assert all(torch.equal(first[key], second[key]) for key in first)  # same seed, same model, on the GPU too
    model = load_checkpoint(tmp_path / "a")  # weights saved from the GPU load on the CPU
    traj = read_trajectory(full_set[1])
    assert np.isfinite(model.generate(np.array([0.0, 0.5]), traj.data[[0, 13]], np.linspace(0, 1, 5)).mean).all()


def test_training_that_learns_nothing_warns_and_records_it_in_the_config(full_set, tmp_path, caplog):
    out = tmp_path / "ckpt"
    with caplog.at_level("WARNING"):
        code = main(
            ["-q", "train", *map(str, full_set), "--out", str(out), "--layout", "motion", "--lr", "1"]
            + ["--steps", "40", "--val-every", "10", "--encoder-widths", "8", "--expert-widths", "8"]
        )
    err = caplog.text
    assert code == 0 and "the model learned nothing" in err and "1000 times the default (lr 1;" in err, err
    result = read_checkpoint_config(out)["result"]
    assert not result["learned"] and result["warning"] in err
    assert result["best_val_error"] >= LEARNED_RATIO * result["mean_prediction_error"] > 0
