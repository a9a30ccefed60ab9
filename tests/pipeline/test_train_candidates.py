"""`cnep train --candidates N`: the checkpoint holds N complete candidate checkpoints, each the lowest validation error
of its part of training, the checkpoint's own weights among them; with 1 (the default) it holds none."""

import json

import pytest
import torch
from safetensors.torch import load_file

from cnep.models import load_checkpoint, read_checkpoint_config
from cnep.models.candidates import Candidates
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.constants import CANDIDATES_DIR, LOG_FILE
from cnep.pipeline.train.stage import train
from tests.pipeline.test_train import full_set, interrupt_at, stage_config  # noqa: F401 (a fixture)

pytestmark = pytest.mark.usefixtures("one_thread")


def test_candidates_are_complete_checkpoints_each_the_best_of_its_part(full_set, tmp_path):  # noqa: F811
    out = train(stage_config(full_set, tmp_path / "ckpt", steps=40, assignment="mixture", candidates=2))
    config = read_checkpoint_config(out)
    assert config["training"]["candidates"] == 2
    log = [json.loads(line) for line in (out / LOG_FILE).read_text().splitlines()]
    folders = sorted((out / CANDIDATES_DIR).iterdir())
    assert len(folders) == 2  # validations at 10, 20, 30, 40: parts 0-20 and 21-40 (mixture keeps from step 0)
    steps = []
    for folder in folders:
        candidate = read_checkpoint_config(folder)
        load_checkpoint(folder)  # complete: its weights match its config
        step, error = candidate["result"]["best_step"], candidate["result"]["best_val_error"]
        part = [e["val_error"] for e in log if (e["step"] - 1) // 20 == (step - 1) // 20]
        assert folder.name == f"step-{step}" and error == min(part)
        assert {k: v for k, v in candidate.items() if k not in ("result", "expert_labels", "config_sha256")} == {
            k: v for k, v in config.items() if k not in ("result", "expert_labels", "config_sha256", "log")
        }
        steps.append(step)
    assert config["result"]["best_step"] in steps
    best = folders[steps.index(config["result"]["best_step"])]
    weights, candidate = load_file(out / "model.safetensors"), load_file(best / "model.safetensors")
    assert all(torch.equal(weights[name], candidate[name]) for name in weights)


def test_one_candidate_writes_none_and_zero_is_refused(full_set, tmp_path):  # noqa: F811
    out = train(stage_config(full_set, tmp_path / "ckpt", steps=20))
    assert not (out / CANDIDATES_DIR).exists() and read_checkpoint_config(out)["training"]["candidates"] == 1
    with pytest.raises(PipelineError, match="candidates must be >= 1"):
        stage_config(full_set, tmp_path / "other", candidates=0)
    assert Candidates(n=2, first=0, last=9).part(9) == 1


def test_an_interrupted_run_resumes_to_the_same_candidates(full_set, tmp_path, monkeypatch):  # noqa: F811
    whole = train(stage_config(full_set, tmp_path / "whole", steps=40, assignment="mixture", candidates=2))
    out = tmp_path / "resumed"
    with monkeypatch.context() as patch:
        interrupt_at(patch, 25)  # the last save was at step 20: the first part's candidate is in the saved state
        with pytest.raises(KeyboardInterrupt):
            train(stage_config(full_set, out, steps=40, assignment="mixture", candidates=2))
    train(stage_config(full_set, out, steps=40, assignment="mixture", candidates=2, resume=True))
    names = sorted(p.name for p in (whole / CANDIDATES_DIR).iterdir())
    assert names == sorted(p.name for p in (out / CANDIDATES_DIR).iterdir()) and len(names) == 2
    for name in names:
        expected, got = (load_file(d / CANDIDATES_DIR / name / "model.safetensors") for d in (whole, out))
        assert all(torch.equal(expected[key], got[key]) for key in expected)
