"""A stopped `cnep sim TASK --out O` keeps the stages it finished in `.O.partial` beside O (pipeline.sim.partial) and
says how to resume; the same command again runs only the stages after them and ends as a straight run does; other
settings, or a finished stage's file changed since, are refused in one line, and `--force` then discards only what
the stopped run wrote. The stages are stood in for here, each writing a file as the stages write theirs (named in its
folder's record); tests/sim/test_stage.py stops and resumes the real ones."""

import errno
import importlib.util
import json
import os

import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

import cnep.pipeline.sim.stage as sim_stage  # noqa: E402
from cnep.outputs import write_output  # noqa: E402
from cnep.pipeline.contract import Terminated  # noqa: E402
from cnep.pipeline.sim.partial import STAGES_FILE, SUMMARY_FILE, partial_folder  # noqa: E402
from cnep.pipeline.sim.stage import CLOSED_LOOP, STAGES  # noqa: E402
from tests.outputs.test_outputs import dead_pid  # noqa: E402
from tests.pipeline.test_contract import assert_one_line, run_cli  # noqa: E402

STOPS = {
    "SIGTERM": (Terminated(), 143),
    "Ctrl-C": (KeyboardInterrupt(), 130),
    "full disk": (OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "x"), 2),
}


POLICIES = ("CNEP-seed0", "CNMP-seed0", "ProMP-seed0")


class Stages:
    """Stand-in stages: each writes `<stage>/made.txt` from the run's seed and returns what it made, the closed loop
    a file per policy, each a part of the stage (PartialRun.part); `stop` (a stage's name, or `closed loop POLICY`)
    writes a leftover, then raises `error`; `ran` lists the stages (and policies) run, in order."""

    def __init__(self, stop: str | None = None, error: BaseException | None = None):
        self.stop, self.error, self.ran = stop, error, []

    def __call__(self, config, task, run) -> dict:
        made = {name: run.stage(name, number, lambda name=name: self.make(run, name, config.seed))
                for number, name in enumerate(STAGES, 1)}  # fmt: skip
        return {"table": "the table", "features": "random", "made": made, "seconds": dict(run.seconds)}

    def make(self, run, name: str, seed: int) -> dict:
        self.ran.append(name)
        folder = run.work / name.replace(" ", "-")
        folder.mkdir(exist_ok=True)
        if name == CLOSED_LOOP:
            kept = run.kept_parts(name)
            for policy in POLICIES:
                if policy not in kept:
                    self.ran.append(f"{name} {policy}")
                    self.write(folder, f"{name} {policy}", f"{policy} of seed {seed}")
                    run.part(name, policy, {"seed": seed}, [folder / f"{name} {policy}.txt"])
            return {policy: {"seed": seed} for policy in POLICIES}
        self.write(folder, name, f"{name} of seed {seed}")
        return {"stage": name, "seed": seed}

    def write(self, folder, name: str, text: str) -> None:
        if name == self.stop:
            write_output(folder / f"{name} half.txt", b"half")  # what the stopped stage wrote before it stopped
            raise self.error
        write_output(folder / ("made.txt" if " " not in name else f"{name}.txt"), text.encode())


def sim(out, capsys, *options):
    return run_cli(["sim", "obstacle", "--out", out, *map(str, options)], capsys)


def without_seconds(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k != "seconds"}


def stopped(tmp_path, capsys, monkeypatch, stop: str = "train", how: str = "Ctrl-C", *options) -> tuple:
    """`cnep sim obstacle --out tmp_path/sim` stopped `how` in the stage `stop`: (out, its status, stderr lines)."""
    out = tmp_path / "sim"
    monkeypatch.setattr(sim_stage, "_run_stages", Stages(stop, STOPS[how][0]))
    code, err = sim(out, capsys, *options)
    return out, code, err


@pytest.mark.parametrize("how", STOPS)
@pytest.mark.parametrize("stop", ["ingest", f"{CLOSED_LOOP} CNMP-seed0"])
def test_a_stopped_sim_keeps_its_finished_stages_and_the_same_command_resumes_them_as_a_straight_run(
    tmp_path, capsys, monkeypatch, stop, how
):
    out, code, err = stopped(tmp_path, capsys, monkeypatch, stop, how)
    partial = partial_folder(out)
    finished = STAGES[: STAGES.index(stop if stop in STAGES else CLOSED_LOOP)]
    assert code == STOPS[how][1] and not out.exists()
    said = assert_one_line(err, "sim", str(partial), ", ".join(finished), "run the same command again")
    assert how != "full disk" or "free some disk space" in said
    assert list(json.loads((partial / STAGES_FILE).read_text())["stages"]) == list(finished)
    (partial / "generate" / f".frame.png.{dead_pid()}-abcdef.tmp").write_bytes(b"")  # a killed worker's temporary

    again = Stages()
    monkeypatch.setattr(sim_stage, "_run_stages", again)
    code, err = sim(out, capsys)
    assert code == 0, err
    assert [s for s in again.ran if s in STAGES] == list(STAGES[len(finished) :])  # finished ones: not run again
    assert not partial.exists() and not list(out.rglob("*half.txt"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim"]
    assert not list(out.rglob("*.tmp"))
    straight = tmp_path / "straight"
    monkeypatch.setattr(sim_stage, "_run_stages", Stages())
    assert sim(straight, capsys)[0] == 0
    resumed, whole = (json.loads((o / SUMMARY_FILE).read_text()) for o in (out, straight))
    assert without_seconds(resumed) == without_seconds(whole)
    assert set(resumed["seconds"]) == set(STAGES)  # the kept stages' times are the stopped run's


def test_the_policies_a_stopped_closed_loop_finished_are_kept(tmp_path, capsys, monkeypatch):
    out, code, err = stopped(tmp_path, capsys, monkeypatch, f"{CLOSED_LOOP} CNMP-seed0")
    assert code == 130 and "run the same command again" in assert_one_line(err, "sim")
    again = Stages()
    monkeypatch.setattr(sim_stage, "_run_stages", again)
    assert sim(out, capsys)[0] == 0
    assert again.ran == [CLOSED_LOOP, f"{CLOSED_LOOP} CNMP-seed0", f"{CLOSED_LOOP} ProMP-seed0"]  # CNEP's: kept
    assert sorted(p.name for p in (out / "closed-loop").iterdir()) == sorted(
        [".cnep-record.json", *(f"{CLOSED_LOOP} {policy}.txt" for policy in POLICIES)]
    )
    assert not (out / "parts").exists()  # the parts go once their stage is recorded whole
    straight = tmp_path / "straight"
    monkeypatch.setattr(sim_stage, "_run_stages", Stages())
    assert sim(straight, capsys)[0] == 0
    resumed, whole = (json.loads((o / SUMMARY_FILE).read_text()) for o in (out, straight))
    assert without_seconds(resumed) == without_seconds(whole)


def test_a_kept_policy_whose_file_changed_runs_again(tmp_path, capsys, monkeypatch):
    out, _, _ = stopped(tmp_path, capsys, monkeypatch, f"{CLOSED_LOOP} ProMP-seed0")
    loop = partial_folder(out) / "closed-loop"
    (loop / f"{CLOSED_LOOP} CNEP-seed0.txt").unlink()  # its part names it: the part is not intact
    again = Stages()
    monkeypatch.setattr(sim_stage, "_run_stages", again)
    assert sim(out, capsys)[0] == 0
    assert again.ran == [CLOSED_LOOP, f"{CLOSED_LOOP} CNEP-seed0", f"{CLOSED_LOOP} ProMP-seed0"]


def test_a_stop_before_any_stage_finished_keeps_nothing(tmp_path, capsys, monkeypatch):
    out, code, err = stopped(tmp_path, capsys, monkeypatch, STAGES[0])
    assert code == 130 and "nothing half-written was kept" in assert_one_line(err, "sim")
    assert list(tmp_path.iterdir()) == []


def test_other_settings_do_not_resume_and_force_discards_only_what_the_stopped_run_wrote(tmp_path, capsys, monkeypatch):
    out, code, _ = stopped(tmp_path, capsys, monkeypatch, "train", "Ctrl-C", "--seed", 1)
    partial = partial_folder(out)
    monkeypatch.setattr(sim_stage, "_run_stages", Stages())
    code, err = sim(out, capsys, "--seed", 2)
    line = assert_one_line(err, "sim", str(partial), "other settings", "seed 1", "--force")
    assert code == 2 and "seed 2" not in line.split("--force")[0]
    (partial / "ingest" / "notes.txt").write_text("mine")  # the user's, in the stopped run's folder
    code, err = sim(out, capsys, "--seed", 2, "--force")
    assert code == 2 and "cnep never deletes your own files" in assert_one_line(err, "sim", "notes.txt")
    assert (partial / "ingest" / "notes.txt").read_text() == "mine"
    assert not (partial / "ingest" / "made.txt").exists() and not (partial / STAGES_FILE).exists()  # the run's: gone
    (partial / "ingest" / "notes.txt").unlink()
    again = Stages()
    monkeypatch.setattr(sim_stage, "_run_stages", again)
    assert sim(out, capsys, "--seed", 2, "--force")[0] == 0
    assert (
        again.ran[: len(STAGES)] == list(STAGES) and (out / "generate" / "made.txt").read_text() == "generate of seed 2"
    )


def test_a_finished_stage_whose_file_changed_is_not_resumed(tmp_path, capsys, monkeypatch):
    out, _, _ = stopped(tmp_path, capsys, monkeypatch, "train")
    made = partial_folder(out) / "ingest" / "made.txt"
    made.write_text("edited")
    monkeypatch.setattr(sim_stage, "_run_stages", Stages())
    code, err = sim(out, capsys)
    assert code == 2 and "cannot be resumed" in assert_one_line(err, "sim", str(made), "--force")
    code, err = sim(out, capsys, "--force")  # the edited file is the user's now: kept, and in the way
    assert code == 2 and "cnep never deletes your own files" in assert_one_line(err, "sim", str(made))
    assert made.read_text() == "edited"


def test_a_users_file_in_the_stopped_runs_folder_is_kept_and_named(tmp_path, capsys, monkeypatch):
    out, _, _ = stopped(tmp_path, capsys, monkeypatch, "train")
    mine = partial_folder(out) / "train" / "notes.txt"
    mine.write_text("mine")
    monkeypatch.setattr(sim_stage, "_run_stages", Stages())
    code, err = sim(out, capsys)
    assert code == 2 and "move it away" in assert_one_line(err, "sim", str(mine))
    assert mine.read_text() == "mine"
    mine.unlink()
    assert sim(out, capsys)[0] == 0


def test_force_starts_a_stopped_run_of_the_same_settings_over(tmp_path, capsys, monkeypatch):
    out, _, _ = stopped(tmp_path, capsys, monkeypatch, "train")
    again = Stages()
    monkeypatch.setattr(sim_stage, "_run_stages", again)
    assert sim(out, capsys, "--force")[0] == 0
    assert again.ran[: len(STAGES)] == list(STAGES) and not partial_folder(out).exists()
