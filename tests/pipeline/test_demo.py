"""`cnep demo --quick` end to end: every stage's files, the summary, and what the .rrd holds."""

import json
import time
from collections import deque
from pathlib import Path

import numpy as np
import pytest

import cnep.pipeline.replay.viewer as L
from cnep.models import CNEPConfig, load_checkpoint, read_checkpoint_config
from cnep.models.assignments import ASSIGNMENTS
from cnep.pipeline.cli.main import main
from cnep.pipeline.demo.config import QUICK
from cnep.pipeline.demo.figure import FIGURE_FILE
from cnep.pipeline.demo.free_choice import gate_census, replay_pick
from cnep.pipeline.demo.generator import CHOICE_KEY, LABEL_KEY
from cnep.pipeline.demo.measures import online_gates
from cnep.pipeline.demo.scene import BEHAVIOURS, FREE_CHOICE, SIDES
from cnep.pipeline.demo.stage import (
    REPLAYS_RRD,
    RRD_FILE,
    SCENE_CHANGE_MARK,
    SUMMARY_FILE,
    expert_labels,
    train_side_by_side,
)
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.replay.decisions import read_decisions
from cnep.pipeline.train.config import checkpoint_conditioning
from cnep.pipeline.train.constants import SCENE
from cnep.recordings import read_demonstration, read_trajectory
from cnep.recordings.constants import STEP_DIM
from cnep.runtime.conditioning import ConditioningPolicy, hand_over
from tests.conftest import PROGRESS_LOG
from tests.pipeline.test_train import stage_config, write_set

N_TRAIN = QUICK.per_behaviour * len(BEHAVIOURS) + QUICK.free_choice_per_side * len(SIDES)
N_HELDOUT = QUICK.heldout_per_behaviour * len(BEHAVIOURS)
N_FREE = QUICK.heldout_free_choice_per_side * len(SIDES)


@pytest.fixture
def demo_run(quick_demo):
    """The session's quick demo (tests/conftest.py), read only."""
    return quick_demo


def _rrd_recordings(path: Path) -> list[dict]:
    """Per Rerun recording in the file: its camera JPEG bytes and gate rows (sorted by frame)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    found = []
    for store in reader.recordings():
        rows = {L.CAMERA: [], L.GATES: []}
        names = None
        for chunk in reader.stream(store=store).to_chunks():
            if chunk.entity_path not in rows:
                continue
            batch = chunk.to_record_batch()
            if chunk.is_static:
                names = batch.column("SeriesLines:names").to_pylist() if chunk.entity_path == L.GATES else names
                continue
            column = "EncodedImage:blob" if chunk.entity_path == L.CAMERA else "Scalars:scalars"
            rows[chunk.entity_path] += zip(batch.column(L.TIMELINE_FRAME).to_pylist(), batch.column(column).to_pylist())
        found.append(
            {
                "frames": [bytes(v[0]) for _, v in sorted(rows[L.CAMERA])],
                "gates": np.array([v for _, v in sorted(rows[L.GATES])]),
                "names": names,
            }
        )
    return found


def test_every_stage_leaves_its_files(demo_run):
    for stage in ("recorded", "demos", "trajectories"):
        counts = {
            split: len(list((demo_run / stage / split).glob("*.mcap")))
            for split in ("train", "heldout", "scene_change", "free_choice")
        }
        assert counts == {"train": N_TRAIN, "heldout": N_HELDOUT, "scene_change": 1, "free_choice": N_FREE}, stage
    recorded = read_demonstration(demo_run / "recorded" / "train" / "demo_000.mcap")
    ingested = read_demonstration(demo_run / "demos" / "train" / "demo_000.mcap")
    assert ingested.frames == recorded.frames  # JPEG kept byte for byte by ingest
    np.testing.assert_allclose(ingested.pose, recorded.pose)
    traj = read_trajectory(demo_run / "trajectories" / "heldout" / "demo_000.mcap")
    assert traj.width == STEP_DIM and traj.n_steps == QUICK.steps
    assert traj.extractor["weights"].startswith("path:extractor.pt")  # held-out files reuse the saved extractor
    assert (demo_run / "extractor.pt").is_file()
    assert read_checkpoint_config(demo_run / "checkpoints" / "cnep")["model"]["n_experts"] == 4
    assert read_checkpoint_config(demo_run / "checkpoints" / "cnmp")["model"]["n_experts"] == 1


def test_both_models_train_the_scene_layout_with_about_the_same_parameters(demo_run):
    """Queries carry time only (the behaviour must come through the context); the CNMP is parameter-matched."""
    sizes = {}
    for name in ("cnep", "cnmp"):
        config = read_checkpoint_config(demo_run / "checkpoints" / name)
        layout = config["layout"]
        assert layout["name"] == SCENE and layout["query"] == [] and layout["observed"][0] == "features"
        assert config["model"]["assignment"] == {"cnep": CNEPConfig().assignment, "cnmp": "paper"}[name]
        assert (
            config["training"]["gate_lr_scale"] == ASSIGNMENTS[config["model"]["assignment"]].gate_lr_scale
        )  # the models'
        sizes[name] = sum(p.numel() for p in load_checkpoint(demo_run / "checkpoints" / name).parameters())
    assert abs(sizes["cnmp"] - sizes["cnep"]) / sizes["cnep"] < 0.01, sizes


def test_no_behaviour_label_reaches_training(demo_run):
    """The labels (behaviour, free-choice scene and pick) are metadata of the recorder's files only: the ingested
    files, the trajectory files and the checkpoints never carry them."""
    recorded = sorted((demo_run / "recorded" / "train").glob("*.mcap"))
    extras = {p.name: read_demonstration(p).episode.extra for p in recorded}
    assert {e[LABEL_KEY] for e in extras.values()} == set(BEHAVIOURS + FREE_CHOICE)  # both kinds are trained on
    assert {e[CHOICE_KEY] for e in extras.values() if CHOICE_KEY in e} <= {"near", "far"}
    for name in extras:
        for stage in ("demos", "trajectories"):
            path = demo_run / stage / "train" / name
            extra = (read_demonstration(path) if stage == "demos" else read_trajectory(path)).episode.extra
            assert LABEL_KEY not in extra and CHOICE_KEY not in extra, (stage, name)
    for model in ("cnep", "cnmp"):
        text = (demo_run / "checkpoints" / model / "config.json").read_text()
        assert not any(name in text for name in BEHAVIOURS + FREE_CHOICE)


def test_summary_covers_behaviours_models_and_the_scene_change(demo_run):
    summary = json.loads((demo_run / SUMMARY_FILE).read_text())
    assert sorted(summary["behaviours"]) == sorted(BEHAVIOURS)
    for row in summary["behaviours"].values():
        assert row["n"] == QUICK.per_behaviour + QUICK.heldout_per_behaviour
        assert row["purity"] == max(row["experts"].values()) / row["n"]
        assert 0 <= row["expert"] < 4
    for model in ("CNEP", "CNMP"):
        row = summary["heldout"][model]
        assert row["n"] == N_HELDOUT and 0 < row["position_rmse_m"] < 1.0 and 0 <= row["wrong_behaviour"] <= N_HELDOUT
        right = row["position_rmse_read_right_m"]  # the RMSE over the scenes read right: all of them, some, none
        if row["wrong_behaviour"] == 0:
            assert right == pytest.approx(row["position_rmse_m"])
        else:
            assert (right is None) == (row["wrong_behaviour"] == N_HELDOUT)
        assert 0 < row["position_rmse_median_m"] <= row["position_rmse_m"] * np.sqrt(N_HELDOUT)
    # offline with an empty hub cache (tests/conftest.py): the training split is extracted with seeded random weights,
    # the others with those weights saved, and the summary says why they are not ImageNet's
    weights = read_trajectory(demo_run / "trajectories" / "train" / "demo_000.mcap").extractor["weights"]
    assert summary["feature_weights"] == weights and weights.startswith("random:seed=0+calibrated")
    assert summary["imagenet_unavailable"] == "none in the torch hub cache and downloading is off"
    (change,) = summary["scene_change"]
    assert "->" in change["behaviour"] and 0 < change["change_step"] < QUICK.steps
    for model in ("CNEP", "CNMP"):
        row = summary["free_choice"][model]
        assert row["n"] == N_FREE and row["valid"] == pytest.approx(row["near"] + row["far"])
        assert row["valid"] + row["between"] == pytest.approx(1.0) and row["distance_m"] >= 0
    (episode,) = summary["free_choice_replay"]
    assert episode["scene"] in FREE_CHOICE and episode["choice"] in ("near", "far")
    assert len(episode["start"]) == 2 and 0 <= episode["expert"] < 4
    census = episode["census"]
    assert census["n"] == N_FREE and 0 <= census["split_commit"] <= census["split"] <= N_FREE
    assert episode["ends_on"] == [b for b, row in summary["behaviours"].items() if row["expert"] == episode["expert"]]
    side = episode["scene"].split("-")[0]
    assert episode["picked"] == (f"{side}-{episode['choice']}" in episode["ends_on"])
    assert set(summary["seconds"]) == {"generate", "ingest", "extract", "train", "replay", "summary"}


def test_the_replayed_free_choice_is_the_one_the_rule_picks(demo_run):
    """The replay_pick rule on every held-out free-choice episode's online gate, as the replay computes it."""
    paths = sorted((demo_run / "trajectories" / "free_choice").glob("*.mcap"))
    traces = online_gates(demo_run / "checkpoints" / "cnep", paths)
    (episode,) = json.loads((demo_run / SUMMARY_FILE).read_text())["free_choice_replay"]
    assert episode["recording"] == paths[replay_pick(traces)].name
    record = {
        Path(r["recording"]).parent.name + "/" + Path(r["recording"]).name: r
        for r in read_decisions(demo_run / REPLAYS_RRD)["recordings"]
    }[f"free_choice/{episode['recording']}"]
    np.testing.assert_allclose(record["gates"], traces[replay_pick(traces)], atol=1e-5)  # what Rerun shows
    assert episode["census"] == gate_census(traces)


def active_experts(gates: np.ndarray, policy: ConditioningPolicy) -> list[int]:
    """The active expert of each step of `gates` (T, d) by `policy`'s rule: the first gate's winner, then
    runtime.conditioning.hand_over."""
    recent, experts = deque(maxlen=policy.switch_window + 1), []
    for gate in gates:
        recent.append(gate)
        experts.append(hand_over(policy, recent, experts[-1]) if experts else int(gate.argmax()))
    return experts


def test_the_rrd_holds_each_replayed_recording(demo_run):
    files = [demo_run / RRD_FILE, *sorted((demo_run / REPLAYS_RRD).parent.glob("*.rrd"))]
    assert [p.name for p in demo_run.glob("*.rrd")] == [RRD_FILE]  # one file to open: the scene change
    (view,) = _rrd_recordings(demo_run / RRD_FILE)
    assert view["frames"] == read_trajectory(demo_run / "trajectories" / "scene_change" / "demo_000.mcap").frames
    recordings = [rec for file in files for rec in _rrd_recordings(file)]
    assert len(recordings) == len(files)
    summary = json.loads((demo_run / SUMMARY_FILE).read_text())
    (choice,) = summary["free_choice_replay"]
    labels = expert_labels(summary["behaviours"])
    checkpoint = demo_run / "checkpoints" / "cnep"
    policy = checkpoint_conditioning(read_checkpoint_config(checkpoint), checkpoint)
    assert labels and all(name in BEHAVIOURS for names in labels.values() for name in names.split(", "))
    replayed = sorted((demo_run / "trajectories" / "heldout").glob("*.mcap")) + [
        demo_run / "trajectories" / "scene_change" / "demo_000.mcap",
        demo_run / "trajectories" / "free_choice" / choice["recording"],
    ]
    assert len(recordings) == len(replayed)
    decisions = {
        Path(r["recording"]).parent.name + "/" + Path(r["recording"]).name: r
        for rrd in (RRD_FILE, REPLAYS_RRD)
        for r in read_decisions(demo_run / rrd)["recordings"]
    }
    for path in replayed:
        frames = read_trajectory(path).frames
        (rec,) = [r for r in recordings if r["frames"] == frames]  # the stored JPEG bytes, one recording each
        assert rec["gates"].shape == (QUICK.steps, 4)
        np.testing.assert_allclose(rec["gates"].sum(1), 1.0, atol=1e-5)
        assert rec["names"] == [L.expert_names(4, labels)]  # each expert named by the behaviours it takes
        experts = decisions[f"{path.parent.name}/{path.name}"]["experts"]
        assert experts == active_experts(rec["gates"], policy)


def test_the_summary_figure_is_a_png(demo_run):
    from PIL import Image

    with Image.open(demo_run / FIGURE_FILE) as image:
        assert image.format == "PNG" and image.width > image.height > 300


def test_a_used_output_folder_is_refused(tmp_path):
    (tmp_path / "something").write_text("x")
    from cnep.pipeline.demo.config import DemoConfig
    from cnep.pipeline.demo.stage import run_demo

    with pytest.raises(PipelineError, match="not empty"):
        run_demo(DemoConfig(out=tmp_path, quick=True, quiet=True))


def test_the_default_output_folder_never_mixes_runs(tmp_path):
    from cnep.pipeline.cli.demo import free_folder

    base = tmp_path / "cnep-demo"
    assert free_folder(base) == base
    base.mkdir()
    assert free_folder(base) == base  # empty: usable
    (base / "summary.json").write_text("{}")
    assert free_folder(base) == tmp_path / "cnep-demo-2"


def test_precision_reaches_every_extraction_quantised_on_the_training_frames(tmp_path, monkeypatch):
    from cnep.pipeline.demo import stage

    def stop(workers, wait=True):  # at training: only the extract calls matter here
        raise PipelineError("stopped before training")

    configs = []
    monkeypatch.setattr(stage, "extract", lambda config: configs.append(config) or [])
    monkeypatch.setattr(stage, "single_thread_processes", stop)
    assert main(["-q", "demo", "--out", str(tmp_path / "run"), "--quick", "--precision", "int8"]) == 2
    train = tmp_path / "run" / "demos" / "train"
    assert [c.inputs[0].name for c in configs] == ["train", "heldout", "scene_change", "free_choice"]
    assert {(c.precision, c.calibrate_on) for c in configs} == {("int8", (train,))}


def test_the_printed_summary_counts_the_scenes_read_wrong_apart_and_names_the_weights():
    from cnep.pipeline.demo.report import features_line, heldout_lines

    row = {"n": 20, "position_rmse_m": 0.0864, "position_rmse_median_m": 0.029, "gripper_mae_m": 0.0029}
    lines = heldout_lines(
        {
            "CNEP": {**row, "wrong_behaviour": 2, "position_rmse_read_right_m": 0.0301},
            "CNMP": {**row, "wrong_behaviour": 20, "position_rmse_read_right_m": None},
        }
    )
    header = lines[2]
    cnep, cnmp = lines[3].split(), lines[4].split()
    assert header.startswith("model  read wrong  position RMSE (cm)  RMSE of those read right (cm)")
    assert cnep[:6] == ["CNEP", "2", "of", "20", "8.64", "3.01"] and cnmp[:6] == ["CNMP", "20", "of", "20", "8.64", "-"]
    assert all(len(line) <= len(header) for line in lines[3:])  # the columns line up under the header
    said = features_line("random:seed=3+calibrated:bias=3.0,frames=256")
    assert "seeded random weights" in said and "(random:seed=3+calibrated:bias=3.0,frames=256)" in said
    assert "ImageNet weights (imagenet:mobilenet_v2-b0353104.pth)" in features_line(
        "imagenet:mobilenet_v2-b0353104.pth"
    )


# The longest silence of a demo's log: ~10 s on an idle machine. A busy machine stretches every stretch of work
# alike, so the bound is also a share of the whole run's wall time.
SILENCE_S, SILENCE_SHARE = 12.0, 0.12


def test_the_demo_is_never_silent_for_long(demo_run):
    """Every stage shows progress (a line at least every LINE_INTERVAL_S while it works, in a log file), the two
    trainings included: one bar per model with its steps, validation error and time left."""
    timed = [line.split(" ", 1) for line in (demo_run.parent / PROGRESS_LOG).read_text().splitlines()]
    times, lines = np.array([float(t) for t, _ in timed]), [line for _, line in timed]
    gaps = np.diff(np.concatenate([[0.0], times]))
    worst = int(np.argmax(gaps))
    bound = max(SILENCE_S, SILENCE_SHARE * times[-1])
    assert gaps[worst] <= bound, (
        f"{gaps[worst]:.1f} s silent (bound {bound:.1f} s of {times[-1]:.0f}) before: {lines[worst]}"
    )
    for model in ("CNEP", "CNMP"):
        bars = [line for line in lines if line.startswith(f"train {model}:")]
        assert bars[0].startswith(f"train {model}:   0%") and f"0/{QUICK.train_steps}" in bars[0]
        assert f"{QUICK.train_steps}/{QUICK.train_steps}" in bars[-1] and "val=" in bars[-1]
    assert any(line.startswith("calibrating random weights on ") for line in lines)
    for split in ("train", "heldout", "scene_change", "free_choice"):
        assert any(line.startswith(f"extract {split}: 100%") for line in lines), split


def test_the_view_marks_where_the_scene_changes(demo_run):
    from tests.pipeline.test_replay import column

    (change,) = json.loads((demo_run / SUMMARY_FILE).read_text())["scene_change"]
    frames, texts = column(demo_run / RRD_FILE, L.SWITCH_LOG, "TextLog:text")
    marked = [frame for frame, text in zip(frames, texts) if SCENE_CHANGE_MARK in text[0]]
    assert marked == [change["change_step"]]


@pytest.mark.slow  # a process of its own, which imports torch
def test_side_by_side_trains_each_job_in_a_process_of_its_own_onto_its_bar(tmp_path, capsys):
    """The full demo's training (the quick one trains in its own process: the test above reads its bars)."""
    job = stage_config(write_set(tmp_path / "data"), tmp_path / "ckpt", steps=10)
    train_side_by_side({"CNEP": job}, quiet=False, started=time.perf_counter())
    assert load_checkpoint(tmp_path / "ckpt").config.n_experts == job.model.n_experts
    bars = [line for line in capsys.readouterr().err.splitlines() if line.startswith("train CNEP:")]
    assert bars[-1].startswith("train CNEP: 100%") and "10/10" in bars[-1] and "loss=" in bars[-1]
