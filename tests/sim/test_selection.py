"""`cnep sim`'s kept checkpoints (pipeline.sim.selection): the candidate that succeeds most on the validation episodes
wins (ties: the lower validation error, then the later step), its weights and config.json become the checkpoint's with
the choice recorded, the candidates go; the validation episodes run online, in every condition, on seeds no summary
reports (pipeline.sim.validation)."""

import importlib.util
import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import cnep.pipeline.sim.selection as selection  # noqa: E402
from cnep.models import read_checkpoint_config  # noqa: E402
from cnep.outputs import RECORD_FILE, is_recorded, writing_as  # noqa: E402
from cnep.pipeline.errors import PipelineError  # noqa: E402
from cnep.pipeline.sim.config import ONLINE, EvalConfig, PickPlaceConfig, SimConfig  # noqa: E402
from cnep.pipeline.sim.selection import (  # noqa: E402
    SELECTION_DIR,
    SELECTION_KEY,
    Candidate,
    candidates_of,
    choose,
    run_seeds,
    select_checkpoints,
    validation_settings,
)
from cnep.pipeline.sim.validation import VALIDATION_RANGE, VALIDATION_SEED_OFFSET, SelectionSettings  # noqa: E402
from cnep.pipeline.train.constants import CANDIDATES_DIR  # noqa: E402
from cnep.pipeline.train.stage import train  # noqa: E402
from cnep.sim.task import DEMO_SEED_OFFSET  # noqa: E402
from cnep.sim.tasks import find_task  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from tests.pipeline.test_train import stage_config, write_set  # noqa: E402
from tests.sim.pick_scripted import pick_policy  # noqa: E402

COMMAND = "sim obstacle"  # the command whose run trains the checkpoints and keeps one


def test_the_highest_success_wins_then_the_lower_validation_error_then_the_later_step():
    a, b, c = Candidate(Path("a"), 10, 0.5), Candidate(Path("b"), 20, 0.4), Candidate(Path("c"), 30, 0.4)
    assert choose([a, b, c], [0.75, 0.5, 0.5]) == a
    assert choose([a, b, c], [0.5, 0.5, 0.25]) == b  # tied success: the lower validation error
    assert choose([a, b, c], [0.5, 0.5, 0.5]) == c  # and at the same error, the later step


def test_validation_seeds_lie_between_the_reported_and_the_demonstrations_and_a_user_cannot_report_them(tmp_path):
    assert VALIDATION_RANGE[0] == VALIDATION_SEED_OFFSET and VALIDATION_RANGE[-1] < DEMO_SEED_OFFSET
    for first, episodes in ((VALIDATION_SEED_OFFSET - 5, 10), (VALIDATION_RANGE[-1], 1)):
        with pytest.raises(PipelineError, match="meet the validation seeds"):
            SimConfig(out=tmp_path / "o", episode_seed=first, episodes=episodes)
        with pytest.raises(PipelineError, match="meet the validation seeds"):
            EvalConfig(policy=tmp_path, episode_seed=first, episodes=episodes)
    with pytest.raises(PipelineError, match="meet the validation seeds"):
        PickPlaceConfig(out=tmp_path / "o", episode_seed=VALIDATION_SEED_OFFSET)
    SimConfig(out=tmp_path / "o", episode_seed=VALIDATION_SEED_OFFSET - 10, episodes=10)  # just below: allowed
    with pytest.raises(PipelineError, match="candidates must be >= 1"):
        SelectionSettings(candidates=0)


def test_a_summary_names_its_reported_seeds_and_the_validation_seeds_that_chose(tmp_path):
    config = SimConfig(out=tmp_path / "o", episodes=20, episode_seed=100, selection=SelectionSettings(3, 4))
    seeds = run_seeds(config)
    assert seeds["reported"] == {"first": 100, "last": 119}
    assert seeds["validation"] == {"first": VALIDATION_SEED_OFFSET, "last": VALIDATION_SEED_OFFSET + 3}
    off = run_seeds(replace(config, selection=SelectionSettings(candidates=1)))
    assert off["validation"] is None and off["validation_range"] == seeds["validation_range"]


def test_validation_episodes_run_online_in_every_condition_on_the_validation_seeds(tmp_path, monkeypatch):
    task = find_task("pick-place", 1)
    config = PickPlaceConfig(out=tmp_path / "o", max_steps=3, selection=SelectionSettings(2, 2))
    settings = validation_settings(config, task)
    assert (settings.protocols, settings.episodes, settings.episode_seed) == ((ONLINE,), 2, VALIDATION_SEED_OFFSET)
    ran = []
    monkeypatch.setattr(selection, "export", lambda export_config: None)
    monkeypatch.setattr(selection, "open_task_policy", lambda path, task: pick_policy((0.1, 0.7, 0.1, 0.1)))
    evaluate = selection.evaluate_policy
    monkeypatch.setattr(selection, "evaluate_policy", lambda *a, **k: ran.append(evaluate(*a, **k)) or ran[-1])

    class Bar:
        def update(self, n, final=False):
            pass

    score = selection._score(config, task.name, tmp_path, "CNEP-seed0/step-4", tmp_path, tmp_path, Bar())
    assert set(score["by_condition"]) == set(task.conditions) == {P.DECIDED, P.FREE, P.CHANGED}
    assert score["success"] == sum(score["by_condition"].values()) / 3  # 3 steps: nothing placed yet
    rows = {c: [r["seed"] for r in rates["per_episode"]] for c, rates in ran[0][ONLINE].items()}
    assert rows == {c: [VALIDATION_SEED_OFFSET, VALIDATION_SEED_OFFSET + 1] for c in task.conditions}


@pytest.fixture
def trained(tmp_path, one_thread) -> dict[str, Path]:
    """Two checkpoints of a tiny run with 3 candidates each (a validation every 10 of 30 steps: one in each part),
    written as a `cnep sim` run writes them."""
    files = write_set(tmp_path / "trajectories")
    with writing_as(COMMAND):
        return {
            label: train(stage_config(files, tmp_path / label, steps=30, assignment="mixture", candidates=3, **extra))
            for label, extra in (("CNEP-seed0", {}), ("CNMP-seed0", {"matched_cnmp": True}))
        }


def test_each_checkpoint_keeps_the_candidate_that_succeeds_most_and_records_the_choice(
    trained, tmp_path, monkeypatch, sim_pools_in_process
):
    candidates = {label: candidates_of(path) for label, path in trained.items()}
    assert all(len(found) == 3 for found in candidates.values())
    # scored by step: the CNEP's middle candidate succeeds most, the CNMP's all alike (its lowest error wins)
    success = {"CNEP-seed0": {0: 0.25, 1: 0.75, 2: 0.5}, "CNMP-seed0": {0: 0.5, 1: 0.5, 2: 0.5}}

    def score(config, task_name, out, name, path, extractor, bar):
        label = name.split("/")[0]
        return {"success": success[label][[c.path for c in candidates[label]].index(path)]}

    monkeypatch.setattr(selection, "_score", score)
    before = {label: {c.step: load_file(c.path / "model.safetensors") for c in found} for label, found in
              candidates.items()}  # fmt: skip
    config = SimConfig(out=tmp_path / "o", max_steps=5, selection=SelectionSettings(3, 2))
    with writing_as(COMMAND):
        records = select_checkpoints(config, find_task("obstacle", 1), tmp_path, trained, tmp_path / "x.pt", workers=2)
    assert not (tmp_path / SELECTION_DIR).exists()
    for label, checkpoint in trained.items():
        found = candidates[label]
        winner = found[1] if label == "CNEP-seed0" else min(found, key=lambda c: (c.val_error, -c.step))
        kept = read_checkpoint_config(checkpoint)
        assert kept[SELECTION_KEY] == records[label] == json.loads(json.dumps(records[label]))
        assert records[label]["kept_step"] == kept["result"]["best_step"] == winner.step
        assert [c["step"] for c in records[label]["candidates"]] == [c.step for c in found]
        assert [c["success"] for c in records[label]["candidates"]] == list(success[label].values())
        assert records[label]["seeds"] == {"first": VALIDATION_SEED_OFFSET, "last": VALIDATION_SEED_OFFSET + 1}
        weights = load_file(checkpoint / "model.safetensors")
        assert all(torch.equal(weights[name], before[label][winner.step][name]) for name in weights)
        assert kept["log"] == "training_log.jsonl" and not (checkpoint / CANDIDATES_DIR).exists()
        assert all(is_recorded(checkpoint / name, COMMAND) for name in ("config.json", "model.safetensors"))
        assert (checkpoint / RECORD_FILE).is_file()


def test_one_candidate_is_no_choice(tmp_path):
    config = SimConfig(out=tmp_path / "o", selection=SelectionSettings(candidates=1))
    assert select_checkpoints(config, find_task("obstacle", 1), tmp_path, {"CNEP-seed0": tmp_path}, tmp_path, 2) == {}


def test_the_command_refuses_reported_seeds_that_meet_the_validation_seeds_in_one_line(tmp_path, capsys):
    from cnep.pipeline.cli.main import main

    code = main(["sim", "obstacle", "--out", str(tmp_path / "o"), "--episode-seed", str(VALIDATION_SEED_OFFSET - 1),
                 "--episodes", "2"])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "meet the validation seeds" in err[0] and not (tmp_path / "o").exists()
