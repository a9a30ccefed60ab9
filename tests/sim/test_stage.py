"""`cnep sim obstacle` end to end on the smallest data that runs every stage (2 demonstrations, random features
calibrated on one batch of frames, 20 training steps, 2 candidate checkpoints chosen on one validation episode, one
episode per protocol cut after 16 steps, recorded) on the environments' latest version, run straight once for the
module: summary.json holds the documented keys and the version, `cnep sim eval` of each exported policy (its task and
version read from the policy) repeats the run's rows with the same settings and episode seeds,
examples/closed_loop_csv.py turns the run into its rows, and a run stopped after a stage and in the closed loop
resumes to the straight run's summary. The stage's pools (training, closed loop) run their jobs in this process
(tests/sim/conftest.py)."""

import importlib.util
import json
import signal
from dataclasses import replace
from pathlib import Path

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.sim.config import ENV_VERSIONS, MODELS, PROTOCOLS, SimConfig  # noqa: E402
from cnep.pipeline.sim.partial import SUMMARY_FILE  # noqa: E402
from cnep.pipeline.sim.stage import run_sim, training_jobs  # noqa: E402
from cnep.pipeline.sim.validation import SelectionSettings  # noqa: E402
from tests.sim.conftest import calibrate_on_few_frames, pools_in_process  # noqa: E402
from tests.test_examples import load  # noqa: E402

# The run's settings, straight and resumed: a choice between 2 candidates, every episode recorded, one view of the
# frames (the views' path at a quarter of the rule's extraction).
SMALL = {
    "demonstrations": 2, "train_steps": 20, "episodes": 1, "max_steps": 16, "record": 1, "offline": True,
    "quiet": True, "selection": SelectionSettings(candidates=2, selection_episodes=1), "views": 1,
}  # fmt: skip


def episode_rows(rates: dict) -> list[dict]:
    """The episodes' rows without their timings."""
    return [{k: v for k, v in row.items() if k != "ms"} for row in rates["per_episode"]]


def own_home(monkeypatch: pytest.MonkeyPatch, root: Path) -> None:
    """HOME and the torch hub's folder under `root` while `monkeypatch` holds."""
    monkeypatch.setenv("HOME", str(root / "home"))
    monkeypatch.setenv("TORCH_HOME", str(root / "torch"))


@pytest.fixture(scope="module")
def straight(tmp_path_factory) -> tuple[SimConfig, dict]:
    """The run straight through, once for the module (its features calibrated on few frames, its pools in this
    process, on one torch thread): its config and summary."""
    import torch

    root, threads = tmp_path_factory.mktemp("sim"), torch.get_num_threads()
    config = SimConfig(out=root / "straight", **SMALL)
    with pytest.MonkeyPatch.context() as monkeypatch:
        own_home(monkeypatch, root)
        calibrate_on_few_frames(monkeypatch)
        pools_in_process(monkeypatch)
        torch.set_num_threads(1)
        try:
            return config, run_sim(config)
        finally:
            torch.set_num_threads(threads)


@pytest.mark.slow  # MobileNet-v2 features, four trainings, two exports, two policies in the loop
def test_cnep_sim_obstacle_writes_the_documented_summary_and_its_policies_repeat_their_episodes(
    straight, tmp_path, monkeypatch, sim_pools_in_process
):
    config, summary = straight
    out = config.out
    own_home(monkeypatch, tmp_path)
    assert json.loads((out / SUMMARY_FILE).read_text()) == json.loads(json.dumps(summary))
    assert summary["demonstrations"] == {"n": 2, "left": 1, "right": 1, "clean": 2}
    assert summary["features"].startswith("random") and summary["settings"]["assignment"] == config.assignment
    assert summary["settings"]["max_steps"] == config.max_steps
    assert summary["seeds"]["reported"] == {"first": 0, "last": 0}
    assert summary["seeds"]["validation"]["first"] > 0  # the choice's episodes are never the reported ones
    assert set(summary["selection"]) == {f"{model}-seed0" for model in MODELS}
    assert summary["env_version"] == summary["settings"]["env_version"] == ENV_VERSIONS[-1]
    assert set(summary["models"]) == set(MODELS) and all(set(seeds) == {"0"} for seeds in summary["models"].values())
    for model, seeds in summary["models"].items():
        assert set(seeds["0"]) == set(PROTOCOLS)
        for rates in seeds["0"].values():
            assert rates["episodes"] == 1 and {"success", "collision", "left", "switched_unchanged"} <= set(rates)
            assert {"policy", "render", "physics"} == set(rates["per_episode"][0]["ms"])
            assert rates["per_episode"][0]["steps"] <= config.max_steps
        # `cnep sim eval` on the exported policy, its task read from the policy, the run's settings and episode seeds
        evaluated = tmp_path / f"eval-{model}"
        policy = out / "policies" / f"{model.lower()}-seed0"
        assert (
            main(["-q", "sim", "eval", str(policy), "--episodes", "1", "--max-steps", "16", "--out", str(evaluated)])
            == 0
        )
        again = json.loads((evaluated / SUMMARY_FILE).read_text())
        assert again["settings"]["task"] == "obstacle" and again["settings"]["max_steps"] == config.max_steps
        assert again["seeds"]["reported"] == summary["seeds"]["reported"]  # the same reported seeds
        assert again["settings"]["env_version"] == ENV_VERSIONS[-1]  # the version it was trained on
        assert {p: episode_rows(r) for p, r in again["results"].items()} == {
            p: episode_rows(r) for p, r in seeds["0"].items()
        }
    rows = load("closed_loop_csv").main([str(out), "--csv", str(tmp_path / "closed-loop.csv")])
    assert [(r["model"], r["protocol"]) for r in rows] == [(m, p) for m in MODELS for p in PROTOCOLS]
    assert rows[0]["success"] == summary["models"]["CNEP"]["0"][PROTOCOLS[0]]["success"] and rows[0]["set"] == 0
    assert len(rows[0]["usage"].split("/")) == config.experts and rows[-1]["usage"] == "1.00"


def without_timings(summary: dict) -> dict:
    """A summary without what the clock measures: the stages' seconds, each episode's milliseconds and the table's
    last column (the policy's milliseconds)."""
    table = [line.rsplit(maxsplit=1)[0] for line in summary["table"].splitlines()]
    summary = json.loads(json.dumps({**summary, "table": table}).replace('"ms":', '"_ms":'), object_hook=_drop_timings)
    return summary


def _drop_timings(entry: dict) -> dict:
    return {k: v for k, v in entry.items() if k not in ("_ms", "seconds")}


@pytest.mark.slow  # the pipeline once more, stopped after the selection and in the closed loop, and resumed
def test_cnep_sim_stopped_after_a_stage_and_in_the_closed_loop_resumes_to_the_summary_of_a_straight_run(
    straight, tmp_path, monkeypatch, few_calibration_frames, sim_pools_in_process, ctrl_c_raises
):
    import cnep.pipeline.sim.stage as sim_stage
    from cnep.outputs import RECORD_FILE
    from cnep.pipeline.sim.partial import PARTS_DIR, STAGES_FILE, PartialRun, partial_folder

    config, straight_summary = straight
    own_home(monkeypatch, tmp_path)
    out = tmp_path / "resumed"
    select = sim_stage.select_checkpoints

    def stopped(*args, **kwargs):
        chosen = select(*args, **kwargs)  # the trained checkpoints changed: Ctrl-C now waits until that is recorded
        signal.raise_signal(signal.SIGINT)  # to this thread, now: Ctrl-C at this point
        return chosen

    monkeypatch.setattr(sim_stage, "select_checkpoints", stopped)
    with pytest.raises(KeyboardInterrupt, match="run the same command again"):
        run_sim(replace(config, out=out))
    assert list(json.loads((partial_folder(out) / STAGES_FILE).read_text())["stages"]) == [
        "generate", "ingest", "extract", "train", "select"
    ]  # fmt: skip
    for finished in ("generate_demonstrations", "train_models", "select_checkpoints"):
        monkeypatch.setattr(sim_stage, finished, None)  # a finished stage is never run again
    record_part, evaluate = PartialRun.part, sim_stage.evaluate_one

    def part_then_stopped(run, *args, **kwargs):
        record_part(run, *args, **kwargs)
        raise KeyboardInterrupt  # Ctrl-C once the closed loop's first policy is recorded

    monkeypatch.setattr(PartialRun, "part", part_then_stopped)
    with pytest.raises(KeyboardInterrupt, match="run the same command again"):
        run_sim(replace(config, out=out))
    monkeypatch.setattr(PartialRun, "part", record_part)
    kept = [p.stem for p in (partial_folder(out) / PARTS_DIR).glob("*/*.json") if p.name != RECORD_FILE]  # the first
    assert len(kept) == 1 and kept[0] in ("CNEP-seed0", "CNMP-seed0")
    evaluated = []
    monkeypatch.setattr(sim_stage, "evaluate_one", lambda *a, **k: evaluated.append(a[3]) or evaluate(*a, **k))
    resumed = run_sim(replace(config, out=out))
    assert evaluated == [{"CNEP-seed0", "CNMP-seed0"}.difference(kept).pop()]  # the kept policy's episodes not rerun
    assert without_timings(resumed) == without_timings(straight_summary)
    assert json.loads((out / SUMMARY_FILE).read_text()) == json.loads(json.dumps(resumed))
    assert sorted(p.name for p in (out / "episodes").iterdir()) == sorted(
        p.name for p in (config.out / "episodes").iterdir()
    )


def test_the_training_settings_given_reach_every_model_the_run_trains(tmp_path):
    config = SimConfig(
        out=tmp_path / "out", train_seeds=(0, 1), assignment="annealed", nll_beta=0.5, feature_components=0,
        train_steps=20, offline=True, quiet=True,
    )  # fmt: skip
    jobs = training_jobs(config, config.out)
    assert sorted(jobs) == ["CNEP-seed0", "CNEP-seed1", "CNMP-seed0", "CNMP-seed1"]
    for label, job in jobs.items():
        assert (job.model.feature_components, job.training.nll_beta, job.training.steps) == (0, 0.5, 20)
        assert job.training.seed == int(label[-1]) and job.matched_cnmp == label.startswith("CNMP")
    assert jobs["CNEP-seed0"].model.assignment == "annealed"
