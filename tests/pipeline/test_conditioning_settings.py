"""Conditioning belongs to the model: chosen at train time, in config.json, the manifest and every Policy made of it,
replaced only where `cnep export`, `cnep run`, `cnep replay` or `cnep sim eval` are given a setting (and say so)."""

import json
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from cnep.models import read_checkpoint_config
from cnep.models.checkpoint import CHECKSUM_KEY, CONFIG_FILE, config_checksum
from cnep.models.config import ConditioningOverrides
from cnep.pipeline.cli.main import main
from cnep.pipeline.export.policy import checkpoint_policy
from cnep.pipeline.replay import read_decisions
from cnep.pipeline.run.stage import open_policy
from cnep.recordings import read_demonstration, read_trajectory, write_demonstration
from cnep.runtime import ConditioningPolicy, load_policy, read_manifest
from cnep.runtime.spec import POSE_NAMES
from tests.pipeline.test_train import write_set
from tests.recordings.factories import demonstration_factory

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = ["--steps", "4", "--val-every", "2", "--warmup-steps", "1", "--batch-size", "4", "--layout", "motion"]
TINY += ["--encoder-widths", "8", "--expert-widths", "8"]


def other_value(name: str) -> object:
    """A value of conditioning setting `name` other than its default: another choice, a larger number."""
    f = next(f for f in fields(ConditioningPolicy) if f.name == name)
    if "choices" in f.metadata:
        return next(choice for choice in f.metadata["choices"] if choice != f.default)
    return f.default / 2 if isinstance(f.default, float) else f.default + 1


def flags(values: dict) -> list[str]:
    return [item for name, value in values.items() for item in (f"--{name.replace('_', '-')}", str(value))]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, dict]:
    """A motion checkpoint trained with every conditioning setting away from its default; and those settings."""
    root = tmp_path_factory.mktemp("conditioning")
    data = write_set(root / "data", features=False)
    chosen = {f.name: other_value(f.name) for f in fields(ConditioningPolicy)}
    assert main(["-q", "train", str(data[0].parent), "--out", str(root / "ckpt"), *TINY, *flags(chosen)]) == 0
    return root / "ckpt", chosen


def test_every_conditioning_setting_of_cnep_train_reaches_config_json_the_manifest_and_the_policies(trained, tmp_path):
    checkpoint, chosen = trained
    assert read_checkpoint_config(checkpoint)["conditioning"] == chosen
    assert main(["-q", "export", str(checkpoint), "--out", str(tmp_path / "policy")]) == 0
    assert read_manifest(tmp_path / "policy").spec.conditioning.to_dict() == chosen
    files = read_checkpoint_config(checkpoint)["files"]
    poses = [read_trajectory(f["path"]).data[:, :7].astype(np.float64) for f in files]  # every file trained on
    largest = dict(zip(POSE_NAMES, np.max([np.abs(np.diff(p, axis=0)).max(axis=0) for p in poses], axis=0).tolist()))
    assert read_checkpoint_config(checkpoint)["max_step"] == largest == read_manifest(tmp_path / "policy").spec.max_step
    for policy in (load_policy(tmp_path / "policy", threads=1), checkpoint_policy(checkpoint, threads=1)):
        assert policy.conditioning.to_dict() == chosen == policy.spec.conditioning.to_dict()


def test_a_setting_given_to_export_run_or_replay_replaces_the_trained_one_and_they_say_so(trained, tmp_path, capsys):
    checkpoint, chosen = trained
    given = {"window": chosen["window"] + 3, "switch_margin": 0.05}
    expected = {**chosen, **given}
    said = f"window {expected['window']} (given; the checkpoint's {chosen['window']})"
    capsys.readouterr()
    assert main(["-q", "export", str(checkpoint), "--out", str(tmp_path / "policy"), *flags(given)]) == 0
    assert said in capsys.readouterr().out
    assert read_manifest(tmp_path / "policy").spec.conditioning.to_dict() == expected
    demo = demonstration_factory(6, frames=False)
    write_demonstration(tmp_path / "demo.mcap", demo)
    for policy, whose in ((tmp_path / "policy", "the policy's"), (checkpoint, "the policy's")):
        out = tmp_path / f"run-{policy.name}.rrd"
        anchors = {"anchors": chosen["anchors"] + 1}
        argv = ["-q", "run", str(policy), str(tmp_path / "demo.mcap"), "--out", str(out), "--fast", *flags(anchors)]
        assert main(argv) == 0
        assert f"anchors {chosen['anchors'] + 1} (given; {whose} {chosen['anchors']})" in capsys.readouterr().out
        summary = json.loads(out.with_name(out.stem + ".summary.json").read_text())
        own = expected if policy.name == "policy" else chosen
        assert summary["conditioning"] == {**own, **anchors} and summary["conditioning_given"] == anchors
    traj = write_set(tmp_path / "trajs", features=False)[0]
    argv = ["-q", "replay", str(checkpoint), str(traj), "--out", str(tmp_path / "r.rrd"), "--no-live"]
    assert main([*argv, *flags({"switch_window": 1})]) == 0
    assert "switch window 1 (given; the checkpoint's" in capsys.readouterr().out
    assert read_decisions(tmp_path / "r.rrd")["policy"] == {**chosen, "switch_window": 1}
    assert main([*argv, "--force"]) == 0  # nothing given: the checkpoint's own
    assert read_decisions(tmp_path / "r.rrd")["policy"] == chosen
    assert read_demonstration(tmp_path / "demo.mcap").n_steps == 6


def test_an_older_checkpoint_without_conditioning_loads_with_the_defaults(trained, tmp_path):
    checkpoint, _ = trained
    older = tmp_path / "older"
    older.mkdir()
    config = json.loads((checkpoint / CONFIG_FILE).read_text())
    for key in ("conditioning", "max_step", CHECKSUM_KEY):
        config.pop(key)
    config[CHECKSUM_KEY] = config_checksum(config)
    (older / CONFIG_FILE).write_text(json.dumps(config))
    (older / "model.safetensors").write_bytes((checkpoint / "model.safetensors").read_bytes())
    policy = checkpoint_policy(older, threads=1)
    assert policy.conditioning == ConditioningPolicy() and policy.spec.max_step is None
    assert main(["-q", "export", str(older), "--out", str(tmp_path / "policy")]) == 0
    assert load_policy(tmp_path / "policy", threads=1).conditioning == ConditioningPolicy()


def test_the_closed_loop_takes_the_policys_own_conditioning_unless_given(trained, monkeypatch):
    import cnep.pipeline.sim.loop as loop
    from cnep.sim.tasks import find_task

    checkpoint, chosen = trained
    opened, task = [], find_task("obstacle", 0)
    monkeypatch.setattr(loop, "open_policy", lambda path, **kwargs: opened.append(kwargs["conditioning"]))
    loop.open_task_policy(checkpoint, task, ConditioningOverrides())
    loop.open_task_policy(checkpoint, task, ConditioningOverrides(window=2, first_expert="argmax"))
    assert opened[0] is None  # the policy's own
    assert opened[1].to_dict() == {**chosen, "window": 2, "first_expert": "argmax"}
    assert open_policy(checkpoint, conditioning=opened[1]).conditioning == opened[1]


def test_a_bad_conditioning_setting_is_refused_in_one_line(trained, tmp_path, capsys):
    checkpoint, _ = trained
    capsys.readouterr()
    assert main(["-q", "export", str(checkpoint), "--out", str(tmp_path / "p"), "--window", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "window must be >= 1" in err and len(err.splitlines()) == 1 and not (tmp_path / "p").exists()


def test_a_sim_run_trains_its_conditioning_into_its_policies(tmp_path):
    from cnep.pipeline.sim.config import PickPlaceConfig, SimConfig, trained_conditioning

    pick = trained_conditioning(
        PickPlaceConfig(out=tmp_path / "p", conditioning=ConditioningOverrides(window=3, anchors=0))
    )
    assert (pick.window, pick.anchors) == (3, 0)
    assert trained_conditioning(PickPlaceConfig(out=tmp_path / "q")) == ConditioningPolicy()  # `cnep train`'s
    given = ConditioningOverrides(first_expert="sample", window=6)
    obstacle = trained_conditioning(SimConfig(out=tmp_path / "o", conditioning=given))
    assert obstacle == replace(ConditioningPolicy(), first_expert="sample", window=6)
    assert trained_conditioning(SimConfig(out=tmp_path / "d")) == ConditioningPolicy()
