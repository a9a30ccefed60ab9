"""Faults lose nothing: kill -9 and SIGTERM at chosen points of every stage, two runs into one output, a full disk.

Each case runs a real `cnep` process paused at one call (tests/pipeline/fault_driver.py), kills it there, and
checks that every output present is complete and equal to an uninterrupted run's, that a polite kill
(SIGTERM) ends with exit 143 and one line and leaves no stray file, and that running the command again
(`--resume` for train) finishes with the uninterrupted run's result and no stray file. A second run into an
output that a live run holds is refused with one line naming the live process. A full disk (a 2 MB tmpfs,
skipped where mounting is not permitted) is exit 2 with one line naming the file and the fix, and leaves
nothing that blocks the next run. The longer soak (random kill times, repeated) is
`python -m benchmarks.soak_faults`.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from cnep.outputs import TEMPORARY
from cnep.pipeline.cli.main import main
from cnep.recordings import read_demonstration, write_demonstration
from tests.conftest import MOTION_TRAINING
from tests.pipeline.fault_driver import files, stray
from tests.pipeline.preloaded import Preloaded
from tests.recordings.factories import demonstration_factory

pytestmark = [pytest.mark.usefixtures("one_thread"), pytest.mark.slow]  # real `cnep` processes, killed and rerun

ROOT = Path(__file__).resolve().parents[2]
TRAINING = MOTION_TRAINING  # what the motion world's checkpoint was trained with
WAIT_S = 240  # a paused process reached its point, or a killed one ended (a loaded 2-core machine is slow)


SERVER: list[Preloaded] = []  # the module's one server (the `preloaded` fixture)


@pytest.fixture(scope="module", autouse=True)
def preloaded() -> Iterator[Preloaded]:
    """The server that forks the `cnep` processes these tests kill, torch already imported (tests/pipeline/
    preloaded.py); a module fixture, so every test here runs on the one worker process that started it."""
    SERVER.append(Preloaded())
    yield SERVER[0]
    SERVER.pop().close()


@dataclass(frozen=True)
class World:
    """Inputs and the outputs of uninterrupted runs (never written to by the tests): tests/conftest.py's
    `motion_world`, and a demonstration cut in its second chunk, for repair."""

    src: Path  # 4 motion CSVs with the usual column names
    demos: Path  # ingested
    trajs: Path  # extracted
    ckpt: Path  # trained with TRAINING
    other_ckpt: Path  # 3 experts: another model for the same recordings
    truncated: Path
    framed: Path  # 3 demonstrations with camera frames


@pytest.fixture(scope="module")
def world(motion_world, tmp_path_factory) -> World:
    root = tmp_path_factory.mktemp("faults")
    big = write_demonstration(root / "big.mcap", demonstration_factory(200, frames=True, frame_size=128))
    (root / "truncated.mcap").write_bytes(big.read_bytes()[: int(big.stat().st_size * 0.7)])
    (root / "framed").mkdir()
    for seed in range(3):
        write_demonstration(root / "framed" / f"d{seed}.mcap", demonstration_factory(6, seed=seed, frame_size=32))
    w = motion_world
    return World(w.src, w.demos, w.trajs, w.ckpt, w.other_ckpt, root / "truncated.mcap", root / "framed")


class Paused:
    """A `cnep` process that will pause at the `hit`-th call of `target` (`module:Attr.name`), forked by the module's
    server; started at once, `wait()` for it to get there (start several, then wait: they run side by side)."""

    def __init__(self, target: str, hit: int, argv: list, tmp: Path):
        self.target, self.hit = target, hit
        self.go = tmp / f".go-{time.monotonic_ns()}"
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
        cmd = [sys.executable, "-m", "tests.pipeline.fault_driver", target, str(hit), str(self.go), "--", "-q"]
        self.proc = SERVER[0].popen([*cmd, *map(str, argv)], cwd=ROOT, env=env)

    def wait(self) -> Paused:
        ready, _, _ = select.select([self.proc.stdout], [], [], WAIT_S)
        line = self.proc.stdout.readline() if ready else ""
        while line and not line.startswith("paused"):  # what the command printed before it paused is skipped
            line = self.proc.stdout.readline()
        if not line.startswith("paused"):
            self.proc.kill()
            raise AssertionError(
                f"never reached {self.target} #{self.hit}: {line!r} {self.proc.communicate()[1][-2000:]}"
            )
        return self

    def stop(self, signum: int) -> tuple[int, list[str]]:
        """Send `signum`, let a deferred signal take effect, wait; (exit status, stderr lines)."""
        self.wait()
        self.proc.send_signal(signum)
        self.go.touch()
        _, err = self.proc.communicate(timeout=WAIT_S)
        self.go.unlink()
        return self.proc.returncode, err.strip().splitlines()

    def release(self) -> tuple[int, list[str]]:
        """Let it go on to the end; (exit status, stderr lines)."""
        self.go.touch()
        _, err = self.proc.communicate(timeout=WAIT_S)
        self.go.unlink()
        return self.proc.returncode, err.strip().splitlines()


def both(target: str, hit: int, argv, tmp: Path) -> dict[int, tuple[int, list[str]]]:
    """Run `argv(out)` killed with SIGKILL and with SIGTERM at the same point, side by side, into tmp/kill and
    tmp/term; {signal: (exit status, stderr lines)}."""
    runs = {signal.SIGKILL: tmp / "kill", signal.SIGTERM: tmp / "term"}
    for folder in runs.values():
        folder.mkdir()
    started = {signum: Paused(target, hit, argv(folder), folder) for signum, folder in runs.items()}
    return {signum: run.stop(signum) for signum, run in started.items()}


def assert_terminated(status: int, err: list[str], command: str, then: str = "nothing half-written was kept") -> None:
    assert status == 143 and len(err) == 1, (status, err)
    assert err[0].startswith(f"cnep {command}: terminated (SIGTERM); {then}"), err


def assert_same_weights(a: Path, b: Path) -> None:
    left, right = load_file(a / "model.safetensors"), load_file(b / "model.safetensors")
    assert left.keys() == right.keys() and all(torch.equal(left[k], right[k]) for k in left)


# --- kill -9 and SIGTERM in every stage ----------------------------------------------------------------------------


def test_ingest_killed_in_the_middle_of_a_file(world, tmp_path):
    stopped = both(
        "cnep.recordings.writers:DemonstrationWriter.write_step",
        60,
        lambda o: ["ingest", world.src, "--out", o / "out"],
        tmp_path,
    )  # the second file half written, the first complete
    reference = files(world.demos)
    assert_terminated(*stopped[signal.SIGTERM], "ingest")
    assert stray(tmp_path / "term") == [] and stopped[signal.SIGKILL][0] == -signal.SIGKILL
    assert len(stray(tmp_path / "kill")) == 2  # the half file's temporary name, the lock
    for run in ("kill", "term"):
        out = tmp_path / run / "out"
        assert files(out).items() <= reference.items() and len(files(out)) == 1
        assert main(["-q", "ingest", str(world.src), "--out", str(out)]) == 0  # no --force: the complete file stays
        assert files(out) == reference and stray(out) == []


def test_extract_killed_between_files(world, tmp_path):
    stopped = both(
        "cnep.recordings.writers:TrajectoryWriter.write_steps",
        3,
        lambda o: ["extract", world.demos, "--out", o / "out"],
        tmp_path,
    )
    reference = files(world.trajs)
    assert_terminated(*stopped[signal.SIGTERM], "extract")
    assert stray(tmp_path / "term") == [] and stopped[signal.SIGKILL][0] == -signal.SIGKILL
    for run in ("kill", "term"):
        out = tmp_path / run / "out"
        assert files(out).items() <= reference.items() and len(files(out)) == 2
        assert main(["-q", "extract", str(world.demos), "--out", str(out)]) == 0
        assert files(out) == reference and stray(out) == []


def test_train_killed_anywhere_resumes_to_the_uninterrupted_weights(world, tmp_path):
    """kill -9 before the first save and after one, SIGTERM (which saves the step it arrived in), and kill -9 while
    --force replaces a checkpoint (the old one stays whole): each re-run ends with the uninterrupted weights."""
    cases = {  # name: (step or None for the publish, signal, what the re-run adds)
        "before-save": (3, signal.SIGKILL, []),  # nothing saved: a plain re-run takes the empty work folder over
        "after-save": (26, signal.SIGKILL, ["--resume"]),
        "sigterm": (26, signal.SIGTERM, ["--resume"]),
        "publish": (None, signal.SIGKILL, ["--resume", "--force"]),
    }
    shutil.copytree(world.other_ckpt, tmp_path / "publish" / "ckpt")
    old = files(tmp_path / "publish" / "ckpt")
    started = {}
    for name, (step, _, _) in cases.items():
        (tmp_path / name).mkdir(exist_ok=True)
        argv = [
            "train",
            world.trajs,
            "--out",
            tmp_path / name / "ckpt",
            *TRAINING,
            *(["--force"] if step is None else []),
        ]
        target = (
            "cnep.pipeline.train.stage:publish" if step is None else "cnep.pipeline.train.stage:StageTrainer.train_step"
        )
        started[name] = (Paused(target, step or 1, argv, tmp_path / name), argv)
    for name, (run, argv) in started.items():
        step, signum, again = cases[name]
        status, err = run.stop(signum)
        out = tmp_path / name / "ckpt"
        if name == "publish":
            assert files(out) == old  # the old checkpoint, whole
        else:
            assert not out.exists()
        if signum == signal.SIGTERM:
            assert_terminated(
                status, err, "train", f"the state of step {step} is in {tmp_path / name / '.ckpt.partial'}"
            )
            assert stray(tmp_path / name) == []
        assert main(["-q", *map(str, argv), *again]) == 0, name
        assert_same_weights(out, world.ckpt)
        assert [p.name for p in (tmp_path / name).iterdir()] == ["ckpt"]  # no work folder, no lock


def test_replay_killed_writes_no_output_and_runs_again(world, tmp_path):
    def argv(folder):
        return [
            "replay",
            world.ckpt,
            *sorted(world.trajs.glob("*.mcap"))[:2],
            "--out",
            folder / "out" / "r.rrd",
            "--no-live",
        ]

    stopped = both("cnep.pipeline.replay.stage:write_recording", 2, argv, tmp_path)
    assert_terminated(*stopped[signal.SIGTERM], "replay")
    assert not (tmp_path / "term" / "out").exists()  # made by the run, removed again
    assert files(tmp_path / "kill" / "out") == {}  # the first recording was staged, never renamed into place
    for run in ("kill", "term"):
        assert main(["-q", *map(str, argv(tmp_path / run))]) == 0
        out = tmp_path / run / "out"
        assert sorted(files(out)) == ["r-01-trajs-demo_0.rrd", "r-02-trajs-demo_1.rrd", "r.experts.json"]
        assert stray(out) == []


FOLDERS = {  # commands that assemble a folder (pipeline.folders): argv into a folder, the output's name, where to stop
    "export": (
        lambda w, t: ["export", w.ckpt, "--out", t / "policy"],
        "policy",
        "cnep.pipeline.export.stage:write_runtime",
        1,
    ),
    "to-lerobot": (
        lambda w, t: ["to-lerobot", w.framed, "--out", t / "ds"],
        "ds",
        "cnep.recordings.lerobot_writer:LerobotWriter.add",
        2,
    ),
}


@pytest.mark.parametrize("command", FOLDERS)
def test_a_folder_killed_while_assembled_is_not_left_and_runs_again(world, tmp_path, command):
    make_argv, name, target, hit = FOLDERS[command]

    def argv(folder):
        return make_argv(world, folder)

    stopped = both(target, hit, argv, tmp_path)
    assert_terminated(*stopped[signal.SIGTERM], command)
    assert list((tmp_path / "term").iterdir()) == []  # the work folder went with the run
    left = sorted(p.name for p in (tmp_path / "kill").iterdir())  # the lock and the work folder of the killed run
    assert len(left) == 2 and TEMPORARY.match(left[0]) and left[1] == f".{name}.lock", left
    for run in ("kill", "term"):
        assert main(["-q", *map(str, argv(tmp_path / run))]) == 0
        assert [p.name for p in (tmp_path / run).iterdir()] == [name]  # a killed run's work folder is removed
    assert files(tmp_path / "kill" / name) == files(tmp_path / "term" / name)


def test_run_killed_writes_no_output_and_runs_again(world, tmp_path):
    def argv(folder):
        recordings = sorted(world.demos.glob("*.mcap"))[:2]
        return ["run", world.ckpt, *recordings, "--out", folder / "out" / "r.rrd", "--fast"]

    stopped = both("cnep.pipeline.run.stage:run_recording", 2, argv, tmp_path)
    assert_terminated(*stopped[signal.SIGTERM], "run")
    assert not (tmp_path / "term" / "out").exists()  # made by the run, removed again
    assert files(tmp_path / "kill" / "out") == {}  # the first recording was staged, never renamed into place
    for run in ("kill", "term"):
        assert main(["-q", *map(str, argv(tmp_path / run))]) == 0
        out = tmp_path / run / "out"
        assert sorted(files(out)) == ["r-01-demos-demo_0.rrd", "r-02-demos-demo_1.rrd", "r.summary.json"]
        assert stray(out) == []


def test_repair_killed_writes_no_output_and_runs_again(world, tmp_path):
    stopped = both(
        "cnep.recordings.container:new_writer", 1, lambda o: ["repair", world.truncated, o / "fixed.mcap"], tmp_path
    )
    assert_terminated(*stopped[signal.SIGTERM], "repair")
    assert stray(tmp_path / "term") == []
    for run in ("kill", "term"):
        assert files(tmp_path / run) == {}
        assert main(["-q", "repair", str(world.truncated), str(tmp_path / run / "fixed.mcap")]) == 0
        assert read_demonstration(tmp_path / run / "fixed.mcap").n_steps > 0 and stray(tmp_path / run) == []


def test_demo_killed_leaves_a_folder_a_forced_run_can_take_over(tmp_path, capsys):
    from cnep.outputs import FOLDER_LOCK, writing_as
    from cnep.pipeline.demo.stage import remove_outputs

    stopped = both(  # random weights: no warning that ImageNet weights are missing
        "cnep.pipeline.demo.stage:ingest",
        1,
        lambda o: ["demo", "--quick", "--weights", "random", "--out", o / "demo"],
        tmp_path,
    )
    assert_terminated(*stopped[signal.SIGTERM], "demo")
    assert not (tmp_path / "term" / "demo").exists()  # a new folder: removed again
    out = tmp_path / "kill" / "demo"
    assert (out / "recorded").is_dir() and stray(out) != []
    capsys.readouterr()
    assert main(["-q", "demo", "--quick", "--out", str(out)]) == 2  # the lock is taken over; the files need --force
    assert "is not empty" in capsys.readouterr().err and stray(out) == []
    with writing_as("demo"):
        remove_outputs(out, out / FOLDER_LOCK)  # what --force does first: everything there was the demo's
    assert list(out.iterdir()) == []


def test_evaluate_terminated_writes_no_table(tmp_path):
    from tests.pipeline.test_contract import QUICK_EVALUATE

    out = tmp_path / "tables"
    argv = ["evaluate", *QUICK_EVALUATE, "--out", out]
    status, err = Paused("cnep.pipeline.evaluate.stage:run_jobs", 1, argv, tmp_path).stop(signal.SIGTERM)
    assert_terminated(status, err, "evaluate")
    assert not out.exists()


# --- two runs into one output: the second is refused naming the first, which finishes ----------------------------


def test_a_second_run_into_a_held_output_is_refused_naming_the_first(world, tmp_path, capsys):
    demos, trajs, rrd, ckpt = tmp_path / "demos", tmp_path / "trajs", tmp_path / "r" / "r.rrd", tmp_path / "ckpt"
    recordings = sorted(world.trajs.glob("*.mcap"))
    runs = [  # (the first run, paused while it holds the output; a second run into the same output)
        (
            Paused(
                "cnep.recordings.writers:DemonstrationWriter.write_step",
                1,
                ["ingest", world.src, "--out", demos],
                tmp_path,
            ),
            ["ingest", world.src, "--out", demos, "--task", "other"],
        ),
        (
            Paused(
                "cnep.recordings.writers:TrajectoryWriter.write_steps",
                1,
                ["extract", world.demos, "--out", trajs],
                tmp_path,
            ),
            ["extract", world.demos, "--out", trajs, "--force"],
        ),
        (
            Paused(
                "cnep.pipeline.replay.stage:write_recording",
                1,
                ["replay", world.ckpt, *recordings, "--out", rrd, "--no-live"],
                tmp_path,
            ),
            ["replay", world.other_ckpt, *recordings, "--out", rrd, "--no-live", "--force"],
        ),
        (
            Paused(
                "cnep.pipeline.train.stage:StageTrainer.train_step",
                15,
                ["train", world.trajs, "--out", ckpt, *TRAINING],
                tmp_path,
            ),
            ["train", world.trajs, "--out", ckpt, *TRAINING, "--resume"],  # as the refusal of a plain re-run advises
        ),
    ]
    for first, second in runs:
        first.wait()
        capsys.readouterr()
        assert main(["-q", *map(str, second)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"another run is writing this output (pid {first.proc.pid} on host" in err[0], err
        assert f"`kill {first.proc.pid}`" in err[0]
    for first, _ in runs:
        assert first.release()[0] == 0
    assert files(demos) == files(world.demos) and files(trajs) == files(world.trajs)
    assert_same_weights(ckpt, world.ckpt)
    assert sorted(files(rrd.parent)) == [f"r-0{i + 1}-trajs-demo_{i}.rrd" for i in range(4)] + ["r.experts.json"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == [] and stray(tmp_path) == []


# --- a full disk ---------------------------------------------------------------------------------------------------


@contextlib.contextmanager
def small_disk(folder: Path, free: int) -> Iterator[Path]:
    """`folder` as a 2 MB tmpfs filled up but for about `free` bytes (needs root and permission to mount; the test is
    skipped elsewhere)."""
    folder.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(folder)]).returncode:
        pytest.skip("mounting a small tmpfs is not permitted here")
    try:
        with open(folder / "filler", "wb") as f:  # fill it, then free a little: the next write of any size fails
            while True:
                try:
                    f.write(b"\0" * 65536)
                    f.flush()
                except OSError:
                    break
        with open(folder / "filler", "r+b") as f:
            f.truncate(max(0, (folder / "filler").stat().st_size - free))
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)])


@pytest.fixture
def full_disk(tmp_path):
    """A 2 MB tmpfs filled up but for a few kB."""
    with small_disk(tmp_path / "disk", 8192) as disk:
        yield disk


def assert_disk_full_line(err: list[str], command: str, disk: Path) -> None:
    assert len(err) == 1 and err[0].startswith(f"cnep {command}: error: {disk}"), err
    assert "No space left on device; free some disk space, or choose a path on another disk" in err[0], err


def test_a_full_disk_is_one_line_naming_the_file_in_every_stage(world, full_disk, capsys):
    demo = write_demonstration(
        world.demos.parent / "framed.mcap", demonstration_factory(30, frames=True, frame_size=64)
    )
    cases = {
        "ingest": ["ingest", world.src, "--out", full_disk / "demos"],
        "extract": [
            "extract",
            demo,
            "--out",
            full_disk / "trajs",
            "--weights",
            "random",
            "--save-weights",
            full_disk / "w.pt",
        ],
        "repair": ["repair", world.truncated, full_disk / "fixed.mcap"],
        "train": ["train", world.trajs, "--out", full_disk / "ckpt", *TRAINING],
        "replay": [
            "replay",
            world.ckpt,
            *sorted(world.trajs.glob("*.mcap")),
            "--out",
            full_disk / "r.rrd",
            "--no-live",
        ],
        "demo": ["demo", "--quick", "--out", full_disk / "demo"],
    }
    for command, argv in cases.items():
        capsys.readouterr()
        assert main(["-q", *map(str, argv)]) == 2, command
        assert_disk_full_line(capsys.readouterr().err.strip().splitlines(), command, full_disk)
        assert sorted(p.name for p in full_disk.iterdir()) == ["filler"], command  # nothing half-written, nothing left
    (full_disk / "filler").unlink()  # space again: nothing from the failed runs blocks the next one
    for command in ("ingest", "train", "replay"):
        assert main(["-q", *map(str, cases[command])]) == 0, command
    assert files(full_disk / "demos") == files(world.demos)
    assert_same_weights(full_disk / "ckpt", world.ckpt)


@pytest.mark.parametrize("free", [0, 64 * 1024, 1000 * 1024])
def test_a_full_disk_names_its_file_in_every_command(world, tmp_path, capsys, monkeypatch, free):
    """With no space left, 64 kB or 1000 kB (some outputs fit, others do not): done, or exit 2 with one line that
    names a file on that disk; nothing half-written either way."""
    import cnep.models.baselines.gmm as gmm_module
    from tests.pipeline.test_contract import QUICK_EVALUATE

    monkeypatch.setattr(gmm_module, "EM_ITERATIONS", 3)  # the evaluation's tables are written, not read: a few EM steps

    with small_disk(tmp_path / "disk", free) as disk:
        cases = {
            "ingest": ["ingest", world.src, "--out", disk / "demos"],
            "to-lerobot": ["to-lerobot", world.framed, "--out", disk / "lerobot"],
            "extract": ["extract", world.demos, "--out", disk / "trajs"],
            "repair": ["repair", world.truncated, disk / "fixed.mcap"],
            "train": ["train", world.trajs, "--out", disk / "ckpt", *TRAINING],
            "replay": ["replay", world.ckpt, world.trajs / "demo_0.mcap", "--out", disk / "r.rrd", "--no-live"],
            "export": ["export", world.ckpt, "--out", disk / "policy"],
            "run": ["run", world.ckpt, world.demos / "demo_0.mcap", "--out", disk / "run.rrd", "--fast"],
            "evaluate": ["evaluate", *QUICK_EVALUATE, "--out", disk / "tables"],
            "demo": ["demo", "--quick", "--weights", "random", "--out", disk / "demo"],
        }
        for command, argv in cases.items():
            capsys.readouterr()
            code = main(["-q", *map(str, argv)])
            err = capsys.readouterr().err.strip().splitlines()
            assert code == 2 or (free and code == 0), (command, code, err)
            if code == 2:
                assert_disk_full_line(err, command, disk)
            assert stray(disk) == [], command
            for path in disk.iterdir():  # the next command gets the same space
                if path.name != "filler":
                    shutil.rmtree(path) if path.is_dir() else path.unlink()


# --- signals from the command's first line to its last -------------------------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_before_the_command_starts_is_one_line(world, tmp_path, signum):
    argv = ["export", world.ckpt, "--out", tmp_path / "policy"]
    status, err = Paused("cnep.pipeline.cli.main:build_parser", 1, argv, tmp_path).stop(signum)
    how = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
    assert status == (143 if signum == signal.SIGTERM else 130) and len(err) == 1, (status, err)
    assert err[0].startswith(f"cnep: {how}; nothing half-written was kept"), err
    assert not (tmp_path / "policy").exists()


@pytest.mark.parametrize("command", ["export", "run"])
def test_a_signal_once_the_command_finished_is_one_line_and_the_outputs_are_complete(world, tmp_path, command):
    """The interpreter's exit (exit handlers, threads) can take a while after the command: a signal there ends it at
    once with one line, where the default action ended it without a word."""
    from cnep.runtime.manifest import read_manifest

    argv = {
        "export": ["export", world.ckpt, "--out", tmp_path / "policy"],
        "run": ["run", world.ckpt, world.demos / "demo_0.mcap", "--out", tmp_path / "r.rrd", "--fast"],
    }[command]
    status, err = Paused("atexit", 1, argv, tmp_path).stop(signal.SIGTERM)
    assert status == 143 and err == [
        f"cnep {command}: terminated (SIGTERM) while exiting; it had finished, its outputs are complete"
    ], (status, err)
    if command == "export":
        assert read_manifest(tmp_path / "policy").files
    else:
        assert (tmp_path / "r.rrd").is_file() and (tmp_path / "r.summary.json").is_file()
    assert stray(tmp_path) == []
