"""Experts named by the task of most of their training demonstrations: in the checkpoint, the replay and the export."""

import dataclasses
from pathlib import Path

import pytest

from cnep.pipeline.export.policy import policy_spec
from cnep.pipeline.replay.stage import replay
from cnep.pipeline.train.checkpoint import load_trained
from cnep.pipeline.train.experts import expert_labels, gate_of
from cnep.pipeline.train.stage import train
from cnep.recordings import read_trajectory, write_trajectory
from cnep.runtime.spec import PolicySpec
from tests.pipeline.test_demo import _rrd_recordings
from tests.pipeline.test_train import stage_config
from tests.recordings.factories import trajectory_factory

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models run on one thread


def test_an_expert_takes_the_task_of_most_of_its_demonstrations():
    experts = {0: 1, 1: 1, 2: 1, 3: 0, 4: 0, 6: 2}  # training-set index -> expert; 5 is a validation file
    tasks = ["pour", "pour", "stack", "stack", "pour", "stack", ""]
    assert expert_labels(experts, tasks) == {1: "pour", 0: "pour"}  # expert 0's tie goes to the first name
    assert expert_labels({0: 0, 1: 1}, ["pour", "pour"]) == {}  # one task names nothing apart
    assert expert_labels({0: 0, 1: 1}, ["", ""]) == {}


def _labelled_set(folder: Path, tasks: list[str]) -> list[Path]:
    folder.mkdir(parents=True)
    paths = []
    for k, task in enumerate(tasks):
        traj = trajectory_factory(20 + k, features=False, seed=k)
        traj = dataclasses.replace(traj, episode=dataclasses.replace(traj.episode, task=task))
        paths.append(write_trajectory(folder / f"demo-{k}.mcap", traj))
    return paths


def test_training_names_its_experts_by_their_demonstrations_tasks_and_replay_and_export_show_them(tmp_path):
    paths = _labelled_set(tmp_path / "data", ["left", "right"] * 4)
    out = tmp_path / "ckpt"
    train(stage_config(paths, out, layout="motion"))
    trained = load_trained(out)
    train_files = [Path(f["path"]).name for f in trained.config["files"] if f["split"] == "train"]
    chosen = {}  # the expert each training demonstration goes to, from the checkpoint as saved
    for k, path in enumerate(paths):
        if path.name in train_files:
            rows = trained.rows(read_trajectory(path), path)
            chosen[k] = int(gate_of(trained.model, rows).argmax())
    tasks = ["left", "right"] * 4
    assert trained.expert_labels == expert_labels(chosen, tasks) != {}
    assert set(trained.expert_labels.values()) <= {"left", "right"}

    replay(out, [paths[0]], tmp_path / "r.rrd", connect=None, quiet=True)
    (shown,) = _rrd_recordings(tmp_path / "r.rrd")
    labels = trained.expert_labels
    names = [f"expert {e} ({labels[e]})" if e in labels else f"expert {e}" for e in range(trained.model.n_experts)]
    assert shown["names"] == [names]  # the gate's series, one per expert

    spec = policy_spec(trained)
    assert spec.expert_labels == tuple(trained.expert_labels.get(e, "") for e in range(spec.n_experts))
    assert PolicySpec.from_dict(spec.to_dict()).expert_labels == spec.expert_labels
    assert trained.config["tasks"] == ["left", "right"] and spec.tasks == ("left", "right")  # what it was trained on


def test_demonstrations_of_one_task_leave_the_experts_their_numbers(tmp_path):
    paths = _labelled_set(tmp_path / "data", ["pick"] * 6)
    train(stage_config(paths, tmp_path / "ckpt", layout="motion", steps=10))
    trained = load_trained(tmp_path / "ckpt")
    assert trained.expert_labels == {} and policy_spec(trained).expert_labels == ()
    assert policy_spec(trained).tasks == ("pick",)
