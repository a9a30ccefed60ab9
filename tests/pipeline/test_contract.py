"""The CLI contract (pipeline/contract.py, docs/reference/cli-contract.md), one test per row, over every subcommand.

Rows: a missing input, a damaged input, an existing output, a read-only output folder and an
interruption each give their exit status (2, 2, 2, 2, 130) and one line on stderr, and leave no
output behind (nor change an existing one). `evaluate` takes no input files, `demo` none but its weights file
(`--weights PATH`), `inspect` writes no output, so those cells are not rows of theirs.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import stat
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from cnep.models.checkpoint import CHECKSUM_KEY, config_checksum
from cnep.outputs import RECORD_FILE
from cnep.pipeline.cli.main import main
from cnep.recordings import Trajectory, write_demonstration, write_trajectory
from tests.recordings.factories import cut_after_header, demonstration_factory
from tests.recordings.sources import baxter_csv

ROOT = Path(__file__).resolve().parents[2]
QUICK_EVALUATE = [
    "--table",
    "comparison",
    "--sets",
    "bimodal",
    "--seeds",
    "1",
    "--steps",
    "2",
    "--queries",
    "1",
    "--jobs",
    "0",
    "--no-figures",
]
TINY_TRAINING = [
    "--layout",
    "motion",
    "--steps",
    "4",
    "--val-every",
    "2",
    "--encoder-widths",
    "8",
    "--expert-widths",
    "8",
    "--batch-size",
    "2",
    "--experts",
    "2",
]


@dataclass(frozen=True)
class World:
    """Inputs shared by the tests (never written to): a CSV source, demonstrations, trajectories, a checkpoint (the
    session's motion world's)."""

    csv: Path
    demos: Path
    trajs: Path
    ckpt: Path
    ckpt_demo: Path  # a demonstration like the checkpoint's training ones (the gripper in their range)
    truncated_demo: Path  # cut inside its second chunk: `cnep repair` salvages the first
    truncated_traj: Path
    empty_chunks: Path  # cut inside its first chunk: nothing to salvage
    short_csv: Path  # a header and one data row


def inside_first_chunk(path: Path) -> float:
    """The fraction of the file `path` that ends in the middle of its first chunk."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        first = make_reader(f).get_summary().chunk_indexes[0]
    return (first.chunk_start_offset + first.chunk_length / 2) / path.stat().st_size


def cut(src: Path, dst: Path, keep: float) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * keep)])
    return dst


@pytest.fixture(scope="module")
def world(tmp_path_factory, motion_world) -> World:
    root = tmp_path_factory.mktemp("contract")
    for name in ("src", "demos", "trajs", "bad"):
        (root / name).mkdir()
    csv = baxter_csv(root / "src" / "a.csv", 6.0 + 15.0 * np.arange(6))
    for i in range(3):
        demo = demonstration_factory(30, frames=False, seed=i, episode_id=f"d{i}")
        write_demonstration(root / "demos" / f"d{i}.mcap", demo)
        write_trajectory(root / "trajs" / f"t{i}.mcap", Trajectory.from_demonstration(demo))
    big = write_demonstration(root / "bad" / "big.mcap", demonstration_factory(400, frames=True, frame_size=64))
    short = root / "bad" / "short.csv"
    short.write_text("\n".join(csv.read_text().splitlines()[:2]) + "\n")
    return World(
        csv=csv,
        demos=root / "demos",
        trajs=root / "trajs",
        ckpt=motion_world.ckpt,  # a motion checkpoint: it replays these trajectories
        ckpt_demo=motion_world.demos / "demo_0.mcap",
        truncated_demo=cut(big, root / "bad" / "truncated-demo.mcap", 0.9),
        truncated_traj=cut(root / "trajs" / "t0.mcap", root / "bad" / "truncated-traj.mcap", 0.6),
        empty_chunks=cut(big, root / "bad" / "no-chunk.mcap", inside_first_chunk(big)),
        short_csv=short,
    )


def run_cli(argv: list, capsys) -> tuple[int, list[str]]:
    """Exit status and stderr lines of `cnep -q ARGV` run in this process (-q: no progress bars)."""
    capsys.readouterr()
    code = main(["-q", *map(str, argv)])
    return code, capsys.readouterr().err.splitlines()


def assert_one_line(lines: list[str], command: str, *words: str) -> str:
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"cnep {command}: "), lines[0]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def leftovers(folder: Path) -> list[str]:
    """Every file and folder under `folder` (relative), or [] if it does not exist."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


# --- missing input: exit 2, one line naming the missing path, no output created -----------------------------------

MISSING_INPUT = {
    "ingest": lambda w, t: ["ingest", t / "nope.csv", "--out", t / "out"],
    "to-lerobot": lambda w, t: ["to-lerobot", t / "nope.mcap", "--out", t / "out" / "ds"],
    "inspect": lambda w, t: ["inspect", t / "nope.mcap"],
    "repair": lambda w, t: ["repair", t / "nope.mcap", t / "out" / "fixed.mcap"],
    "extract": lambda w, t: ["extract", t / "nope.mcap", "--out", t / "out"],
    "train": lambda w, t: ["train", w.trajs, t / "nope.mcap", "--out", t / "out"],
    "replay": lambda w, t: ["replay", w.ckpt, t / "nope.mcap", "--out", t / "out" / "r.rrd", "--no-live"],
    "export": lambda w, t: ["export", t / "nope", "--out", t / "out" / "policy"],
    "run": lambda w, t: ["run", w.ckpt, t / "nope.mcap", "--out", t / "out" / "r.rrd", "--fast"],
    "demo": lambda w, t: ["demo", "--quick", "--weights", t / "nope.pth", "--out", t / "out"],
}


@pytest.mark.parametrize("command", MISSING_INPUT)
def test_a_missing_input_is_one_line_and_exit_2(world, tmp_path, capsys, command):
    code, err = run_cli(MISSING_INPUT[command](world, tmp_path), capsys)
    assert code == 2
    assert_one_line(err, command, "error: ", str(tmp_path / "nope"))
    assert not (tmp_path / "out").exists()


# --- damaged input: exit 2, one line naming the damaged file and the problem, no output created --------------------

DAMAGED_INPUT = {
    "ingest": lambda w, t: (["ingest", w.short_csv, "--out", t / "out"], w.short_csv, "found a header and 1 data row"),
    "to-lerobot": lambda w, t: (
        ["to-lerobot", w.truncated_demo, "--out", t / "out" / "ds"],
        w.truncated_demo,
        "cnep repair",
    ),
    "inspect": lambda w, t: (["inspect", w.truncated_demo], w.truncated_demo, "truncated"),
    "repair": lambda w, t: (["repair", w.empty_chunks, t / "out" / "fixed.mcap"], w.empty_chunks, "nothing to salvage"),
    "extract": lambda w, t: (["extract", w.truncated_demo, "--out", t / "out"], w.truncated_demo, "cnep repair"),
    "train": lambda w, t: (["train", w.trajs, w.truncated_traj, "--out", t / "out"], w.truncated_traj, "truncated"),
    "replay": lambda w, t: (
        ["replay", w.ckpt, w.truncated_traj, "--out", t / "out" / "r.rrd", "--no-live"],
        w.truncated_traj,
        "truncated",
    ),
    "run": lambda w, t: (
        ["run", w.ckpt, w.truncated_demo, "--out", t / "out" / "r.rrd", "--fast"],
        w.truncated_demo,
        "truncated",
    ),
}


@pytest.mark.parametrize("command", DAMAGED_INPUT)
def test_a_damaged_input_is_one_line_and_exit_2(world, tmp_path, capsys, command):
    argv, damaged, problem = DAMAGED_INPUT[command](world, tmp_path)
    before = damaged.read_bytes()
    code, err = run_cli(argv, capsys)
    assert code == 2
    line = assert_one_line(err, command, "error: ", str(damaged), problem)
    if command != "inspect":  # inspect reports on stdout and exits 2; the others name the fix in the line
        assert "; " in line.split(str(damaged), 1)[1]
    assert not (tmp_path / "out").exists() and damaged.read_bytes() == before


# --- existing output: exit 2 and the output unchanged without --force; with --force a file the command wrote is
# --- replaced, a user's own file at that path is refused (exit 2, unchanged) -------------------------------------

EXISTING_OUTPUT = {  # argv, the output path to pre-fill, whether --force is quick enough to try here
    "ingest": lambda w, t: (["ingest", w.csv, "--out", t / "out"], t / "out" / "a.mcap", True),
    "to-lerobot": lambda w, t: (["to-lerobot", w.demos, "--out", t / "out" / "ds"], t / "out" / "ds", True),
    "repair": lambda w, t: (["repair", w.truncated_demo, t / "out" / "fixed.mcap"], t / "out" / "fixed.mcap", True),
    "extract": lambda w, t: (["extract", w.demos, "--out", t / "out"], t / "out" / "d1.mcap", True),
    "train": lambda w, t: (["train", w.trajs, "--out", t / "out" / "ckpt", *TINY_TRAINING], t / "out" / "ckpt", True),
    "replay": lambda w, t: (
        ["replay", w.ckpt, w.trajs / "t0.mcap", "--out", t / "out" / "r.rrd", "--no-live"],
        t / "out" / "r.experts.json",
        True,
    ),
    "export": lambda w, t: (["export", w.ckpt, "--out", t / "out" / "policy"], t / "out" / "policy", True),
    "run": lambda w, t: (
        ["run", w.ckpt, w.ckpt_demo, "--out", t / "out" / "r.rrd", "--fast"],
        t / "out" / "r.summary.json",
        True,
    ),
    "evaluate": lambda w, t: (["evaluate", *QUICK_EVALUATE, "--out", t / "out"], t / "out" / "comparison.md", False),
    "demo": lambda w, t: (["demo", "--quick", "--out", t / "out"], t / "out" / "notes.txt", False),
}


@pytest.mark.parametrize("command", EXISTING_OUTPUT)
def test_an_existing_output_is_never_overwritten_without_force(world, tmp_path, capsys, command, one_thread):
    argv, existing, try_force = EXISTING_OUTPUT[command](world, tmp_path)
    existing.parent.mkdir(parents=True, exist_ok=True)
    existing.write_bytes(b"precious")
    before = leftovers(tmp_path / "out")
    code, err = run_cli(argv, capsys)
    assert code == 2
    assert_one_line(err, command, "error: ", str(existing.parent), "--force")
    assert existing.read_bytes() == b"precious" and leftovers(tmp_path / "out") == before
    if try_force:
        code, err = run_cli([*argv, "--force"], capsys)
        assert code == 2 and existing.read_bytes() == b"precious" and leftovers(tmp_path / "out") == before
        assert_one_line(err, command, str(existing), "--force replaces only", "never deletes your own files")
        existing.unlink()
        assert run_cli(argv, capsys)[0] == 0  # now the output is the command's own ...
        written = leftovers(tmp_path / "out")
        code, err = run_cli([*argv, "--force"], capsys)  # ... and --force replaces it
        assert code == 0, err
        assert leftovers(tmp_path / "out") == written


def test_an_output_that_is_a_file_where_a_folder_is_expected_is_one_line(world, tmp_path, capsys):
    (tmp_path / "file").write_text("keep")
    for argv in (
        ["extract", world.demos, "--out", tmp_path / "file"],
        ["demo", "--out", tmp_path / "file"],
        ["ingest", world.csv, "--out", tmp_path / "file"],
    ):
        code, err = run_cli(argv, capsys)
        assert code == 2 and "is a file" in assert_one_line(err, argv[0], str(tmp_path / "file"))
    assert (tmp_path / "file").read_text() == "keep"


# --- read-only output folder: exit 2, one line, nothing written ----------------------------------------------------


@pytest.fixture
def read_only(tmp_path):
    """An existing folder nobody can write in (chattr +i for root, who ignores permission bits)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(folder)]).returncode != 0:
            pytest.skip("running as root without chattr +i: no way to make a folder read-only here")
        yield folder
        subprocess.run(["chattr", "-i", str(folder)], check=True)
    else:
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)


READ_ONLY_OUTPUT = {
    "ingest": lambda w, ro: ["ingest", w.csv, "--out", ro / "out"],
    "to-lerobot": lambda w, ro: ["to-lerobot", w.demos, "--out", ro / "ds"],
    "repair": lambda w, ro: ["repair", w.truncated_demo, ro / "fixed.mcap"],
    "extract": lambda w, ro: ["extract", w.demos, "--out", ro],
    "train": lambda w, ro: ["train", w.trajs, "--out", ro / "ckpt", *TINY_TRAINING],
    "replay": lambda w, ro: ["replay", w.ckpt, w.trajs / "t0.mcap", "--out", ro / "r.rrd", "--no-live"],
    "export": lambda w, ro: ["export", w.ckpt, "--out", ro / "policy"],
    "run": lambda w, ro: ["run", w.ckpt, w.ckpt_demo, "--out", ro / "r.rrd", "--fast"],
    "evaluate": lambda w, ro: ["evaluate", *QUICK_EVALUATE, "--out", ro / "tables"],
    "demo": lambda w, ro: ["demo", "--quick", "--out", ro / "demo"],
}


@pytest.mark.parametrize("command", READ_ONLY_OUTPUT)
def test_a_read_only_output_folder_is_one_line_and_exit_2(world, read_only, capsys, command, one_thread):
    code, err = run_cli(READ_ONLY_OUTPUT[command](world, read_only), capsys)
    assert code == 2
    assert_one_line(err, command, "error: ", str(read_only))
    assert leftovers(read_only) == []


# --- interrupted: exit 130, one line, nothing half-written and no folder left --------------------------------------


def interrupt(*args, **kwargs):
    raise KeyboardInterrupt


INTERRUPTED = {  # argv, and the function replaced by one that interrupts (Ctrl-C in the middle of the work)
    "ingest": lambda w, t: (["ingest", w.csv, "--out", t / "out"], "cnep.recordings.writers", "new_writer"),
    "to-lerobot": lambda w, t: (
        ["to-lerobot", w.demos, "--out", t / "out" / "ds"],
        "cnep.recordings.lerobot_writer",
        "step_columns",
    ),
    "inspect": lambda w, t: (["inspect", w.demos / "d0.mcap"], "cnep.recordings.inspection", "read_mcap"),
    "repair": lambda w, t: (
        ["repair", w.truncated_demo, t / "out" / "fixed.mcap"],
        "cnep.recordings.container",
        "new_writer",
    ),
    "extract": lambda w, t: (["extract", w.demos, "--out", t / "out"], "cnep.recordings.writers", "new_writer"),
    "train": lambda w, t: (
        ["train", w.trajs, "--out", t / "out" / "ckpt", *TINY_TRAINING],
        "cnep.pipeline.train.stage",
        "save_progress",
    ),
    "replay": lambda w, t: (
        ["replay", w.ckpt, w.trajs / "t0.mcap", "--out", t / "out" / "r.rrd", "--no-live"],
        "cnep.pipeline.replay.stage",
        "write_recording",
    ),
    "export": lambda w, t: (
        ["export", w.ckpt, "--out", t / "out" / "policy"],
        "cnep.pipeline.export.stage",
        "write_runtime",
    ),
    "run": lambda w, t: (
        ["run", w.ckpt, w.ckpt_demo, "--out", t / "out" / "r.rrd", "--fast"],
        "cnep.pipeline.run.stage",
        "run_recording",
    ),
    "evaluate": lambda w, t: (
        ["evaluate", *QUICK_EVALUATE, "--out", t / "out"],
        "cnep.pipeline.evaluate.stage",
        "run_jobs",
    ),
    "demo": lambda w, t: (  # random weights: no warning that ImageNet weights are missing
        ["demo", "--quick", "--weights", "random", "--out", t / "out"],
        "cnep.pipeline.demo.stage",
        "ingest",
    ),
}


@pytest.mark.parametrize("command", INTERRUPTED)
def test_an_interruption_is_exit_130_and_leaves_nothing_half_written(
    world, tmp_path, capsys, monkeypatch, command, one_thread
):
    argv, module, name = INTERRUPTED[command](world, tmp_path)
    monkeypatch.setattr(importlib.import_module(module), name, interrupt)
    code, err = run_cli(argv, capsys)
    assert code == 130
    assert_one_line(err, command, "interrupted")
    if command == "train":  # the state saved so far stays beside the output, by design: --resume continues it
        assert {p.split("/")[0] for p in leftovers(tmp_path / "out")} <= {".ckpt.partial"}
    else:
        assert leftovers(tmp_path / "out") == [] and not (tmp_path / "out").exists()


# --- the other rows: --version, no torch for inspect, broken pipes, bugs, umask, --keep-going --------------------


def test_version_is_printed(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    from importlib.metadata import version

    assert capsys.readouterr().out.strip() == f"cnep {version('cnep-pipeline')}"


def test_inspect_does_not_import_torch(world):
    code = (
        "import sys; from pipeline.cli.main import main; status = main(['inspect', sys.argv[1]]); "
        "print('torch' in sys.modules, status, file=sys.stderr)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(world.demos / "d0.mcap")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.stderr.strip().splitlines()[-1] == "False 0", done.stderr


REFUSED_BEFORE_LOADING = {
    "train": ["train", "does/not/exist", "--out", "x"],
    "extract": ["extract", "does/not/exist", "--out", "x"],
    "replay": ["replay", "does/not/exist", "r.mcap", "--out", "x.rrd", "--no-live"],
    "export": ["export", "does/not/exist", "--out", "x"],
    "to-lerobot": ["to-lerobot", "does/not/exist", "--out", "x"],
    "run": ["run", "does/not/exist", "r.mcap", "--out", "x.rrd"],
    "demo": ["demo", "--weights", "does/not/exist", "--out", "x"],
    "help": ["train", "--help"],
}


@pytest.mark.parametrize("case", REFUSED_BEFORE_LOADING)
def test_a_missing_path_is_refused_before_torch_onnx_and_rerun_load(case, tmp_path):
    code = (
        "import sys\n"
        "from cnep.pipeline.cli.main import main\n"
        "try:\n"
        "    status = main(sys.argv[1:])\n"
        "except SystemExit as done:\n"
        "    status = done.code\n"
        "loaded = sorted(m for m in ('torch', 'onnx', 'onnxruntime', 'rerun') if m in sys.modules)\n"
        "print(status, loaded, file=sys.stderr)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, *REFUSED_BEFORE_LOADING[case]],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    *message, last = done.stderr.strip().splitlines()
    assert last == ("0 []" if case == "help" else "2 []"), done.stderr
    assert case == "help" or (len(message) == 1 and "does/not/exist" in message[0]), message
    assert not (tmp_path / "x").exists()


def test_a_reader_that_stops_reading_ends_inspect_quietly(world):
    """`cnep inspect A B | head -1`: no BrokenPipeError traceback, exit 0."""
    files = [str(world.demos / f"d{i}.mcap") for i in range(3)] * 20
    proc = subprocess.Popen(
        [sys.executable, "-m", "cnep.pipeline", "inspect", *files],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.readline()
    proc.stdout.close()  # what `head -1` does after its line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0 and err == "", err


def test_a_bug_is_exit_1_with_one_line_and_v_shows_the_traceback(world, tmp_path, capsys, monkeypatch):
    def broken(*args, **kwargs):
        raise TypeError("an internal slip")

    monkeypatch.setattr(importlib.import_module("cnep.recordings.inspection"), "read_mcap", broken)
    code, err = run_cli(["inspect", world.demos / "d0.mcap"], capsys)
    assert code == 1
    assert_one_line(err, "inspect", "internal error (TypeError: an internal slip)", "this is a bug", "-v")
    capsys.readouterr()
    assert main(["-v", "inspect", str(world.demos / "d0.mcap")]) == 1
    assert "Traceback (most recent call last)" in capsys.readouterr().err


def test_a_user_error_shows_its_traceback_only_with_v(world, tmp_path, capsys):
    argv = ["repair", str(tmp_path / "nope.mcap"), str(tmp_path / "out.mcap")]
    assert main(argv) == 2 and "Traceback" not in capsys.readouterr().err
    assert main(["-v", *argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("cnep repair: error: ")


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_files_are_written_with_the_users_umask(world, tmp_path, capsys, umask):
    old = os.umask(umask)
    try:
        assert run_cli(["ingest", world.csv, "--out", tmp_path / "demos"], capsys)[0] == 0
        assert run_cli(["repair", tmp_path / "demos" / "a.mcap", tmp_path / "fixed.mcap"], capsys)[0] == 0
        assert (
            run_cli(["replay", world.ckpt, world.trajs / "t0.mcap", "--out", tmp_path / "r.rrd", "--no-live"], capsys)[
                0
            ]
            == 0
        )
    finally:
        os.umask(old)
    for path in (
        tmp_path / "demos" / "a.mcap",
        tmp_path / "fixed.mcap",
        tmp_path / "r.rrd",
        tmp_path / "r.experts.json",
    ):
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask, path


def test_ingest_keep_going_writes_the_good_sources_and_names_the_bad_one(world, tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    for name in ("a", "b", "d"):
        shutil.copy(world.csv, src / f"{name}.csv")
    shutil.copy(world.short_csv, src / "c.csv")
    code, err = run_cli(["ingest", src, "--out", tmp_path / "strict"], capsys)
    assert code == 2 and str(src / "c.csv") in assert_one_line(err, "ingest")  # without --keep-going: stops at c
    assert sorted(p.name for p in (tmp_path / "strict").iterdir()) == [RECORD_FILE, "a.mcap", "b.mcap"]  # complete only
    code, err = run_cli(["ingest", src, "--out", tmp_path / "out", "--keep-going"], capsys)
    assert code == 2
    assert_one_line(err[-1:], "ingest", "1 of 4 input(s) skipped, the other 3 were written to", str(src / "c.csv"))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [RECORD_FILE, "a.mcap", "b.mcap", "d.mcap"]


def test_extract_keep_going_extracts_the_good_files_and_names_the_bad_one(world, tmp_path, capsys):
    inputs = tmp_path / "in"
    shutil.copytree(world.demos, inputs)
    shutil.copy(world.truncated_traj, inputs / "e.mcap")
    code, err = run_cli(["extract", inputs, "--out", tmp_path / "out", "--keep-going"], capsys)
    assert code == 2
    assert_one_line(err[-1:], "extract", "1 of 4 input(s) skipped", str(inputs / "e.mcap"), "truncated")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [RECORD_FILE, "d0.mcap", "d1.mcap", "d2.mcap"]


# --- messages that used to mislead --------------------------------------------------------------------------------


def test_a_checkpoint_with_edited_n_experts_is_one_line(world, tmp_path, capsys):
    ckpt = tmp_path / "ckpt"
    shutil.copytree(world.ckpt, ckpt)
    config = json.loads((ckpt / "config.json").read_text())
    config["model"]["n_experts"] = 3
    (ckpt / "config.json").write_text(json.dumps(config))
    argv = ["replay", ckpt, world.trajs / "t0.mcap", "--out", tmp_path / "r.rrd", "--no-live"]
    code, err = run_cli(argv, capsys)
    assert code == 2 and "does not match its checksum" in assert_one_line(err, "replay", str(ckpt))
    config[CHECKSUM_KEY] = config_checksum(config)  # even with a matching checksum: one line, not torch's dump
    (ckpt / "config.json").write_text(json.dumps(config))
    code, err = run_cli(argv, capsys)
    assert code == 2 and "weights do not match config.json" in assert_one_line(err, "replay", str(ckpt))


def test_a_checkpoint_file_instead_of_its_folder_is_one_line(world, tmp_path, capsys):
    code, err = run_cli(
        ["replay", world.ckpt / "config.json", world.trajs / "t0.mcap", "--out", tmp_path / "r.rrd", "--no-live"],
        capsys,
    )
    assert code == 2 and "is a file; pass the checkpoint folder" in assert_one_line(err, "replay")


def test_training_on_demonstrations_says_to_extract_first(world, tmp_path, capsys):
    code, err = run_cli(["train", world.demos, "--out", tmp_path / "ckpt"], capsys)
    assert code == 2
    assert_one_line(err, "train", "is a 'demonstration' file, expected a 'trajectory' file", "run `cnep extract`")


def test_inspect_names_a_frame_that_does_not_decode(world, tmp_path, capsys):
    demo = demonstration_factory(12, frames=True)
    demo.frames[10] = cut_after_header(demo.frames[10])  # a JPEG's header, then nothing to decode
    path = write_demonstration(tmp_path / "bad-frame.mcap", demo)
    code, err = run_cli(["inspect", path], capsys)
    assert code == 2
    assert_one_line(err, "inspect", str(path), "frame 10 on /camera/rgb is not a decodable JPEG")


def test_inspect_does_not_suggest_repair_when_nothing_can_be_salvaged(world, capsys):
    code, err = run_cli(["inspect", world.empty_chunks], capsys)
    out = capsys.readouterr().out  # the report was printed before run_cli read stderr; nothing more here
    assert code == 2 and "nothing can be salvaged" in err[0] and "cnep repair" not in err[0] + out


def test_train_fits_the_warm_up_into_few_steps_and_says_so(world, tmp_path, caplog, one_thread):
    import logging

    with caplog.at_level(logging.WARNING):
        assert main(["-q", "train", str(world.trajs), "--out", str(tmp_path / "ckpt"), *TINY_TRAINING]) == 0
    training = json.loads((tmp_path / "ckpt" / "config.json").read_text())["training"]
    assert training["warmup_steps"] == 2 and "warmup_steps" not in training["schedule"]["given"]  # half the 4 steps
    assert "warm-up" not in caplog.text
    caplog.clear()
    out = str(tmp_path / "ckpt2")
    with caplog.at_level(logging.WARNING):
        assert main(["-q", "train", str(world.trajs), "--out", out, *TINY_TRAINING, "--warmup-steps", "9"]) == 0
    assert "a warm-up of 9 steps in 4 steps: the learning rate never reaches its peak" in caplog.text


def test_train_help_shows_the_actual_defaults():
    import dataclasses

    from cnep.models import TrainConfig
    from cnep.pipeline.cli.train import default

    defaults = {f.name: f.default for f in dataclasses.fields(TrainConfig) if "help" in f.metadata}
    assert {name: default(name) for name in defaults} == defaults
    done = subprocess.run(
        [sys.executable, "-m", "cnep.pipeline", "train", "--help"], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert "TrainConfig's default" not in done.stdout and "(default the training schedule's" in done.stdout
