"""`cnep run`: a policy stepped through demonstration recordings into Rerun, with the step-time summary."""

import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import cnep.pipeline.replay.viewer as L
from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.replay.rerun_log import first_read_text
from cnep.pipeline.run import RunConfig, run, summarise
from cnep.pipeline.run.stage import open_policy
from cnep.pipeline.train.stage import train
from cnep.recordings import read_demonstration, write_demonstration
from cnep.runtime import TimeBase
from tests.pipeline.test_expert_labels import _labelled_set
from tests.pipeline.test_replay import column
from tests.pipeline.test_train import stage_config
from tests.recordings.factories import demonstration_factory
from tests.runtime.test_torch_free import run_without_torch

RERUN = Path(sys.executable).parent / "rerun"


@pytest.fixture(autouse=True)
def rerun_env(tmp_path, monkeypatch):
    """The rerun CLI (used by verify) writes analytics under HOME unless CI is set."""
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("HOME", str(home))


def rrd_verify(path: Path) -> subprocess.CompletedProcess:
    exe = str(RERUN) if RERUN.exists() else shutil.which("rerun")
    return subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)


def test_run_steps_each_recording_into_an_rrd_and_summarises_the_step_times(policy_world, tmp_path, capsys):
    recordings = [policy_world.heldout, policy_world.demos / "demo_000.mcap"]
    out = tmp_path / "out" / "run.rrd"
    code = main(["-q", "run", str(policy_world.exported), *map(str, recordings), "--out", str(out), "--fast"])
    assert code == 0
    files = sorted((tmp_path / "out").glob("run-*.rrd"))  # one file per recording, in the order given
    assert [f.name for f in files] == ["run-01-heldout-demo_000.rrd", "run-02-train-demo_000.rrd"]
    for file in files:
        assert rrd_verify(file).returncode == 0
    summary = json.loads((tmp_path / "out" / "run.summary.json").read_text())
    assert [r["recording"] for r in summary["recordings"]] == list(map(str, recordings))
    for entry in [*summary["recordings"], summary["total"]]:
        assert {"steps", "p50_ms", "p99_ms", "max_ms", "over_budget", "switches"} <= set(entry)
        assert 0 < entry["p50_ms"] <= entry["p99_ms"] <= entry["max_ms"]
    steps = [read_demonstration(p).n_steps for p in recordings]
    assert [r["steps"] for r in summary["recordings"]] == steps and summary["total"]["steps"] == sum(steps)
    assert summary["recordings"][0]["frame_period_ms"] == pytest.approx(100)  # the demo records at 10 Hz
    printed = capsys.readouterr().out
    assert "total" in printed and "p99 ms" in printed and str(out) in printed
    # the lane shows the active expert, or "unsure" where it holds less than SURE_GATE; the log opens with the read
    _, gates = column(files[0], L.GATES, "Scalars:scalars")
    shown = [L.UNSURE if max(g) < L.SURE_GATE else f"expert {int(np.argmax(g))}" for g in gates]
    state_frames, states = column(files[0], L.ACTIVE_EXPERT, "StateChange:state")
    assert state_frames == [k for k in range(len(shown)) if k == 0 or shown[k] != shown[k - 1]]
    assert states == [[shown[k]] for k in state_frames]
    _, texts = column(files[0], L.SWITCH_LOG, "TextLog:text")
    assert texts[0][0] == first_read_text(np.array(gates[0]), shown[0] != L.UNSURE)
    code = main(["-q", "run", str(policy_world.exported), str(policy_world.heldout), "--out", str(out), "--fast"])
    assert code == 2  # the .rrd exists: refused without --force
    summary_file = tmp_path / "out" / "run.summary.json"
    summary_file.write_text("my notes")
    argv = ["-q", "run", str(policy_world.exported), str(policy_world.heldout), "--out", str(out), "--fast", "--force"]
    assert main(argv) == 2 and summary_file.read_text() == "my notes"  # --force replaces only what cnep run wrote


def test_a_checkpoint_runs_on_torch_with_its_extractor(policy_world, tmp_path):
    config = RunConfig(
        policy_world.checkpoint, (policy_world.heldout,), tmp_path / "r.rrd", extractor=policy_world.extractor,
        threads=1, realtime=False,
    )  # fmt: skip
    runs = run(config)
    steps = read_demonstration(policy_world.heldout).n_steps
    assert len(runs) == 1 and len(runs[0].step_s) == steps and np.all(runs[0].step_s > 0)
    assert summarise(runs)["total"]["steps"] == steps and (tmp_path / "r.summary.json").is_file()


def test_a_time_base_given_to_run_replaces_the_policys(policy_world):
    args = build_parser().parse_args(["run", "p", "r.mcap", "--out", "r.rrd", "--time-base", "7,0.5"])
    assert args.time_base == TimeBase(7.0, 0.5)
    assert open_policy(policy_world.exported, threads=1).time_base != args.time_base
    assert open_policy(policy_world.exported, threads=1, time_base=args.time_base).time_base == args.time_base


def test_run_paces_steps_at_the_recordings_rate(policy_world, tmp_path):
    """Steps 0.1 s apart take at least (steps - 1) x 0.1 s at the recording's rate."""
    import time

    start = time.perf_counter()
    run(RunConfig(policy_world.exported, (policy_world.heldout,), tmp_path / "r.rrd", threads=1))
    assert time.perf_counter() - start >= 0.1 * (read_demonstration(policy_world.heldout).n_steps - 1)


def test_run_refuses_a_recording_without_frames_for_a_policy_that_sees(policy_world, tmp_path, capsys):
    write_demonstration(tmp_path / "blind.mcap", demonstration_factory(5, frames=False))
    capsys.readouterr()
    code = main(
        ["-q", "run", str(policy_world.exported), str(tmp_path / "blind.mcap"), "--out", str(tmp_path / "r.rrd")]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert "blind.mcap" in err and "frames" in err and not (tmp_path / "r.rrd").exists()
    code = main(["-q", "run", str(tmp_path), str(tmp_path / "blind.mcap"), "--out", str(tmp_path / "r.rrd")])
    assert code == 2 and "neither an exported policy" in capsys.readouterr().err


def test_cnep_run_of_an_exported_policy_needs_no_torch(policy_world, tmp_path):
    done = run_without_torch(
        f"""
        from cnep.pipeline.cli.main import main
        code = main(["-q", "run", {str(policy_world.exported)!r}, {str(policy_world.heldout)!r}, "--out", "r.rrd",
                     "--fast", "--threads", "1"])
        assert code == 0, code
        """,
        tmp_path,
    )
    assert done.returncode == 0, done.stderr
    steps = read_demonstration(policy_world.heldout).n_steps
    assert json.loads((tmp_path / "r.summary.json").read_text())["total"]["steps"] == steps


def test_run_warns_in_one_line_when_a_recording_names_a_task_the_policy_was_not_trained_on(
    tmp_path, caplog, one_thread
):
    checkpoint = tmp_path / "ckpt"
    train(stage_config(_labelled_set(tmp_path / "data", ["left", "right"] * 2), checkpoint, layout="motion", steps=10))
    for task in ("left", "pour"):
        demo = demonstration_factory(8, frames=False, seed=1)
        write_demonstration(tmp_path / f"{task}.mcap", replace(demo, episode=replace(demo.episode, task=task)))
    caplog.clear()
    run(RunConfig(checkpoint, (tmp_path / "left.mcap",), tmp_path / "a.rrd", realtime=False, quiet=True))
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
    run(RunConfig(checkpoint, (tmp_path / "left.mcap", tmp_path / "pour.mcap"), tmp_path / "b.rrd", realtime=False,
                  quiet=True))  # fmt: skip
    (warning,) = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert "'pour'" in warning and "'left', 'right'" in warning and "'left' (" not in warning
    assert len(warning.splitlines()) == 1
