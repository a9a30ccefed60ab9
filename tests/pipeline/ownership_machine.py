"""Ownership as a property, checked on random histories (Hypothesis' rule-based state machine): a user's files put
beside and inside cnep's outputs (at an output's own path too, an output edited, folders named like the ones cnep sets
an output aside in or trains in), cnep commands run on them with and without --force (in this process, or in a process
of their own stopped by SIGTERM, SIGINT or kill -9 at a random point of its writing, then run again), the user
deleting files of theirs; `cnep sim obstacle`, its stages stood in for (`SimStages`: each writes a file as the
stages write theirs), stopped after a stage and run again with the same or another seed, with and without --force.

After every step: every byte of the user's is where the user put it; every other file under the folder is complete,
named unchanged by the record of its folder (or, in a policy folder, by its manifest), or the leftover of a killed
process (a temporary file, a lock) that the next run clears; a command ends with exit 0, 2 (one line that never
blames a leftover of an interrupted run) or the status of its signal, never 1; a command that ends with 0 wrote all
its outputs.

    seen = run_machine(world, base, examples=8, steps=8, server=Preloaded())   # tests/pipeline/test_ownership_state.py
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import select
import shutil
import signal
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    precondition,
    rule,
    run_state_machine_as_test,
)

from cnep.models.checkpoint import CONFIG_FILE as CONFIG
from cnep.outputs import (
    RECORD_FILE,
    TEMPORARY,
    WRITER_ENV,
    foreign_files,
    is_lock_name,
    is_recorded,
    output_lock,
    pid_alive,
    read_record,
    recorded_by,
    write_output,
    writing_as,
)
from cnep.pipeline.cli.main import main
from cnep.pipeline.demo.stage import remove_outputs
from cnep.pipeline.export.stage import in_manifest
from cnep.pipeline.replay.decisions import decisions_path
from cnep.pipeline.run.stage import summary_path
from cnep.pipeline.sim import stage as sim_stage
from cnep.pipeline.sim.stage import STAGES as SIM_STAGES
from cnep.pipeline.train.constants import STATE_FILE
from cnep.runtime.constants import MANIFEST_FILE
from tests.pipeline.preloaded import Preloaded
from tests.pipeline.test_contract import TINY_TRAINING

ROOT = Path(__file__).resolve().parents[2]
SIGNALLED = {signal.SIGTERM: (143, -signal.SIGTERM), signal.SIGINT: (130, -signal.SIGINT), signal.SIGKILL: (-9,)}
LEFTOVER = re.compile(r"\.\S+\.\d+-[0-9a-f]{6}\.tmp|\.lock\b|\.replaced-\d+")  # what a killed run leaves behind
WAIT_S = 240  # a command in a process of its own ends (a loaded 2-core machine is slow)
# Where a command in a process of its own is stopped: as it stages a file, as it commits its files (before the
# renames, and inside, where the record is written before and after them); a command that replaces a folder also as it
# sets the old one aside and empties it; training also in a step.
POINTS = (
    "cnep.outputs.record:record_entries",
    "cnep.outputs.record:rename_recorded",
    "cnep.outputs.atomic:Staging.path",
)
FOLDER_POINTS = ("cnep.outputs.folders:set_aside", "cnep.outputs.folders:discard")
TRAIN_POINTS = ("cnep.pipeline.train.stage:StageTrainer.train_step",)


@dataclass(frozen=True)
class World:
    """The inputs every history reads (never written): 4 motion CSVs, their demonstrations, trajectories and a
    checkpoint `cnep train` wrote (tests/conftest.py `motion_world`), a demonstration cut in its second chunk (for
    `repair`), a quick demo's folder (copied into each history) or None, and a dead process's id."""

    src: Path
    demos: Path
    trajs: Path
    ckpt: Path
    truncated: Path
    demo: Path | None
    dead_pid: int


@dataclass(frozen=True)
class Command:
    """A command of a history: its argv, the outputs an exit 0 leaves, and the folder they are in or are (`home`)."""

    argv: list
    made: list[Path]
    home: Path
    points: tuple[str, ...] = POINTS  # where it may be stopped (fault_driver's targets)


def commands(w: World, r: Path) -> dict[str, Command]:
    """The commands a history runs in its folder `r`, by name."""
    demo0, traj0 = sorted(w.demos.glob("*.mcap"))[0], sorted(w.trajs.glob("*.mcap"))[0]
    names = [p.with_suffix(".mcap").name for p in sorted(w.src.glob("*.csv"))]
    replay, runs = r / "replay" / "r.rrd", r / "runs" / "r.rrd"
    return {
        "ingest": Command(["ingest", w.src, "--out", r / "demos"], [r / "demos" / n for n in names], r / "demos"),
        "extract": Command(["extract", w.demos, "--out", r / "trajs"], [r / "trajs" / n for n in names], r / "trajs"),
        "train": Command(
            ["train", w.trajs, "--out", r / "ckpt", *TINY_TRAINING],
            [r / "ckpt" / CONFIG],
            r / "ckpt",
            POINTS + FOLDER_POINTS + TRAIN_POINTS,
        ),
        "train its own": Command(
            ["train", r / "trajs", "--out", r / "ckpt", *TINY_TRAINING], [], r / "ckpt", POINTS + TRAIN_POINTS
        ),
        "replay": Command(
            ["replay", w.ckpt, traj0, "--out", replay, "--no-live"], [replay, decisions_path(replay)], replay.parent
        ),
        "run": Command(["run", w.ckpt, demo0, "--out", runs, "--fast"], [runs, summary_path(runs)], runs.parent),
        "run inside its input": Command(
            ["run", r / "ckpt", demo0, "--out", r / "ckpt" / "runs" / "r.rrd", "--fast"], [], r / "ckpt"
        ),
        "export": Command(
            ["export", w.ckpt, "--out", r / "policy"],
            [r / "policy" / MANIFEST_FILE],
            r / "policy",
            POINTS + FOLDER_POINTS,
        ),
        "repair": Command(["repair", w.truncated, r / "fixed" / "f.mcap"], [r / "fixed" / "f.mcap"], r / "fixed"),
        "demo": Command(["demo", "--quick", "--out", r / "demo"], [r / "demo" / "summary.json"], r / "demo"),
        **{
            name: Command(
                ["sim", "obstacle", "--out", r / "sim", "--seed", seed], [r / "sim" / "summary.json"], r / "sim"
            )
            for name, seed in SIM_SEEDS.items()
        },
    }


SIM_SEEDS = {"sim": 0, "sim with another seed": 1}  # `cnep sim obstacle --seed`: a run of other settings
# The keys of `commands`, and the other choices of a step, riskiest first: Hypothesis tries the first ones first.
COMMANDS = ("train", "export", "demo", "sim", "ingest", "extract", "run", "replay", "repair", "train its own")
COMMANDS += ("run inside its input", "sim with another seed")
FORCE = st.sampled_from([True, False])
STOP = {  # a command in a process of its own, and where to stop it: `Command.points[point]`, at its `hit`-th call
    "command": st.sampled_from([c for c in COMMANDS if c != "demo" and c not in SIM_SEEDS]),
    "force": FORCE,
    "signum": st.sampled_from([signal.SIGKILL, signal.SIGTERM, signal.SIGINT]),
    "point": st.integers(0, 99),
    "hit": st.integers(1, 3),
}
NAMES = ("notes.txt", "demo_0.mcap", CONFIG, "model.safetensors", "state.pt", "r.rrd", MANIFEST_FILE, "summary.json")
# Where a user's file goes, relative to a command's outputs: at an output's own path, inside its folder (deeper too),
# beside it, in folders named like the ones a run sets an output aside in, and in a training's work folder.
WHERE = ("inside", "at", "deeper", "aside", "aside of a dead run", "work folder", "beside")
HOMES = {"ckpt": "train", "policy": "export", "demo": "demo", "demos": "ingest", "trajs": "extract", "runs": "run"}
HOMES |= {"replay": "replay", "fixed": "repair", "sim": "sim"}  # a command's folder -> the command


class SimStages:
    """`cnep sim`'s stages stood in for (pipeline.sim.stage._run_stages, while `run_machine` runs): each stage writes
    `<stage>/made.txt` of the run's seed as the stages write their files (cnep.outputs.write_output); the stage `stop`
    writes `<stage>/half.txt`, then raises KeyboardInterrupt (Ctrl-C) (None: every stage finishes)."""

    stop: str | None = None

    def __call__(self, config, task, run) -> dict:
        made = {name: run.stage(name, number, lambda name=name: self.make(run.work, name, config.seed))
                for number, name in enumerate(SIM_STAGES, 1)}  # fmt: skip
        return {"table": "", "features": "", "made": made, "seconds": run.seconds}

    def make(self, work: Path, name: str, seed: int) -> dict:
        folder = work / name.replace(" ", "-")
        folder.mkdir(exist_ok=True)
        if name == self.stop:
            write_output(folder / "half.txt", b"half")
            raise KeyboardInterrupt
        write_output(folder / "made.txt", f"{name} of seed {seed}".encode())
        return {"seed": seed}


def place(where: str, command: Command, name: str, dead_pid: int) -> Path:
    """Where a user's file named `name` goes, `where` relative to `command`'s outputs."""
    home = command.home
    return {
        "at": command.made[0] if command.made else home / name,
        "inside": home / name,
        "deeper": home / "mine" / name,
        "beside": home.parent / name,
        "aside": home.parent / f".{home.name}.replaced" / name,
        "aside of a dead run": home.parent / f".{home.name}.replaced-{dead_pid}-abcdef" / name,
        "work folder": home.parent / f".{home.name}.partial" / name,
    }[where]


class Ownership(RuleBasedStateMachine):
    """One history in a new folder under `base` (the class's inputs are set by `run_machine`)."""

    world: World
    base: Path
    server: Preloaded | None = None
    demo_runs: bool = False  # whether a quick demo may run whole (else its --force is tried in this process)
    seen: Counter  # (command, how it ended: "done", "refused", the signal's name) -> how many times

    def __init__(self) -> None:
        super().__init__()
        self.root = Path(tempfile.mkdtemp(dir=self.base))
        self.user: dict[Path, bytes] = {}
        self.interrupted: list | None = None

    @initialize(outputs=st.sampled_from([True, False]), stopped=st.sampled_from([True, False]), **STOP)
    def start(self, outputs: bool, stopped: bool, **stop) -> None:
        """An empty folder, or one holding outputs already (the world's, copied with their records); in half the
        histories (those Hypothesis tries first among them), a command stopped by a signal first."""
        if outputs:
            for name, source in (("demos", self.world.demos), ("trajs", self.world.trajs), ("ckpt", self.world.ckpt)):
                shutil.copytree(source, self.root / name)
            if self.world.demo is not None:
                shutil.copytree(self.world.demo, self.root / "demo")
        if stopped and self.server is not None:
            self.stop_a_command(**stop)

    # --- what the user does ---------------------------------------------------------------------------------------

    @rule(
        command=st.sampled_from(COMMANDS),
        where=st.sampled_from(WHERE),
        name=st.sampled_from(NAMES),
        data=st.binary(max_size=32),
    )
    def put_a_file(self, command: str, where: str, name: str, data: bytes) -> None:
        self.put(place(where, commands(self.world, self.root)[command], name, self.world.dead_pid), data)

    @precondition(lambda self: self.user)
    @rule(pick=st.integers(0, 10_000))
    def delete_a_file(self, pick: int) -> None:
        path = sorted(self.user)[pick % len(self.user)]
        path.unlink()
        del self.user[path]

    # --- what cnep does, with a file of the user's where it writes ------------------------------------------------

    @rule(
        command=st.sampled_from(COMMANDS),
        force=FORCE,
        mine=st.lists(st.tuples(st.sampled_from(WHERE), st.sampled_from(NAMES), st.binary(max_size=8)), max_size=2),
    )
    def run_a_command(self, command: str, force: bool, mine: list) -> None:
        chosen = commands(self.world, self.root)[command]
        for where, name, data in mine:
            self.put(place(where, chosen, name, self.world.dead_pid), data)
        self.run(command, force)

    @precondition(lambda self: self.outputs())
    @rule(pick=st.integers(0, 10_000), data=st.binary(max_size=8), force=FORCE)
    def edit_an_output_and_run_its_command_again(self, pick: int, data: bytes, force: bool) -> None:
        outputs = self.outputs()
        path = outputs[pick % len(outputs)]
        self.put(path, data)  # the user's file now, though its folder's record names it
        self.run(HOMES[path.relative_to(self.root).parts[0]], force)

    def run(self, command: str, force: bool) -> None:
        """Run `command` in this process (the quick demo only where it is refused at once, unless `demo_runs`)."""
        chosen = commands(self.world, self.root)[command]
        argv = [*chosen.argv, *(["--force"] if force else [])]
        if command == "demo" and not self.demo_runs and self.demo_would_run(force):
            if force and chosen.home.is_dir():  # what --force does before a demo runs again, in this process
                with writing_as("demo"), output_lock(chosen.home, folder=True) as lock:
                    remove_outputs(chosen.home, lock)
            return
        self.expect(self.in_process(argv), chosen.made)

    def outputs(self) -> list[Path]:
        """The files cnep wrote in the folders of the commands, sorted (records, locks and temporaries left out)."""
        homes = [self.root / home for home in HOMES]
        found = [p for home in homes if home.is_dir() for p in home.rglob("*") if p.is_file() and not p.is_symlink()]
        return sorted(p for p in found if p not in self.user and not bookkeeping(p.name))

    @precondition(lambda self: self.server is not None)
    @rule(**STOP)
    def stop_a_command(self, command: str, force: bool, signum: int, point: int, hit: int) -> None:
        chosen = commands(self.world, self.root)[command]
        argv = [*chosen.argv, *(["--force"] if force else [])]
        status, err = self.signalled(argv, signum, chosen.points[point % len(chosen.points)], hit)
        assert status in (0, 2, *SIGNALLED[signum]), (argv, status, err)
        if status in (0, 2):
            self.expect((status, err), chosen.made)
        else:
            self.interrupted = argv

    @rule(
        command=st.sampled_from(list(SIM_SEEDS)),
        force=FORCE,
        stop=st.sampled_from(SIM_STAGES),
        mine=st.lists(st.tuples(st.sampled_from(WHERE), st.sampled_from(NAMES), st.binary(max_size=8)), max_size=2),
    )
    def stop_the_sim(self, command: str, force: bool, stop: str, mine: list) -> None:
        """`cnep sim` stopped by Ctrl-C in the stage `stop` (in this process: its stages are stood in for here)."""
        chosen = commands(self.world, self.root)[command]
        for where, name, data in mine:
            self.put(place(where, chosen, name, self.world.dead_pid), data)
        SimStages.stop = stop
        try:
            status, _ = self.in_process([*chosen.argv, *(["--force"] if force else [])], stopped=True)
        finally:
            SimStages.stop = None
        if status == 130:
            self.interrupted = chosen.argv

    @precondition(lambda self: self.interrupted is not None)
    @rule()
    def run_it_again(self) -> None:
        argv, self.interrupted = self.interrupted, None
        if argv[0] == "train":  # what its one line says to do, when it saved a state
            out = Path(argv[argv.index("--out") + 1])
            argv = [*argv, *(["--resume"] if (out.parent / f".{out.name}.partial" / STATE_FILE).is_file() else [])]
        self.in_process(argv)

    def put(self, path: Path, data: bytes) -> None:
        """The user writes `data` at `path` (an output's own path too: the user's file now), unless a file is where a
        folder of the path would be, or a folder where the file would be."""
        if path.is_dir() or any(p.is_file() or p.is_symlink() for p in path.parents if p.is_relative_to(self.root)):
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        self.user[path] = data

    def demo_would_run(self, force: bool) -> bool:
        """Whether `cnep demo --quick` would run whole (a new or empty folder, or --force on a demo's own) rather than
        be refused at once."""
        out = self.root / "demo"
        fresh = not out.exists() or not any(out.iterdir())
        return fresh or force and not foreign_files(out, recorded_by("demo"))

    # --- what must hold -------------------------------------------------------------------------------------------

    @invariant()
    def every_user_byte_is_there(self) -> None:
        for path, data in self.user.items():
            assert path.is_file() and path.read_bytes() == data, path

    @invariant()
    def every_other_file_is_complete_or_a_killed_runs_leftover(self) -> None:
        for path in sorted(self.root.rglob("*")):
            if path in self.user or path.is_dir() and not path.is_symlink():
                continue
            assert complete(path, self.root, self.user), f"{path}: not the user's, nor complete, nor a dead run's"

    def teardown(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)

    # --- running commands -----------------------------------------------------------------------------------------

    def in_process(self, argv: list, stopped: bool = False) -> tuple[int, list[str]]:
        """`cnep -q ARGV` in this process: (exit status, stderr lines); `stopped`: it may end interrupted (130)."""
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = main(["-q", *map(str, argv)])
        assert WRITER_ENV not in os.environ, "a command left its name behind"
        lines = err.getvalue().splitlines()
        if status == 2:  # one line (warnings go to the log), and not about what an interrupted run left
            assert lines and lines[-1].startswith(f"cnep {argv[0]}: error: "), (argv, lines)
            said = lines[-1]
            for path in self.user:  # a file of the user's may be named anything
                said = said.replace(str(path), "")
            assert not LEFTOVER.search(said), (argv, lines[-1])
        assert status in (0, 2, *([130] if stopped else [])), (argv, status, lines)
        self.seen[argv[0], {0: "done", 2: "refused"}.get(status, "SIGINT")] += 1
        return status, lines

    def signalled(self, argv: list, signum: int, point: str, hit: int) -> tuple[int, list[str]]:
        """`cnep -q ARGV` in a process of its own, sent `signum` where it begins the `hit`-th call of `point`
        (tests/pipeline/fault_driver.py), unless it ends before; (exit status, stderr lines)."""
        env = {k: v for k, v in os.environ.items() if k != WRITER_ENV}
        env.update(CI="1", HOME=str(self.base), OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
        go = Path(tempfile.mkdtemp(dir=self.base)) / "go"
        driver = [sys.executable, "-m", "tests.pipeline.fault_driver", point, str(hit), str(go), "--", "-q"]
        child = self.server.popen([*driver, *map(str, argv)], cwd=ROOT, env=env)
        line = "start"
        while line and not line.startswith("paused"):  # what the command prints before it pauses is skipped
            ready, _, _ = select.select([child.stdout], [], [], WAIT_S)
            line = child.stdout.readline() if ready else ""
        if line.startswith("paused"):
            child.send_signal(signum)
            go.touch()  # a signal it holds off takes effect when it goes on
            self.seen["signal sent", signal.Signals(signum).name] += 1
        _, err = child.communicate(timeout=WAIT_S)
        shutil.rmtree(go.parent)
        ended = {0: "done", 2: "refused"}.get(child.returncode, signal.Signals(signum).name)
        self.seen[argv[0], ended] += 1
        return child.returncode, err.splitlines()

    def expect(self, result: tuple[int, list[str]], made: list[Path]) -> None:
        """An exit 0 left every output of the command, complete."""
        status, err = result
        if status == 0:
            for path in made:
                assert path.is_file() and complete(path, self.root, self.user), (path, err)


def bookkeeping(name: str) -> bool:
    """A record, a temporary file or a lock file: cnep's, but no output."""
    return name == RECORD_FILE or TEMPORARY.match(name) is not None or is_lock_name(name)


def complete(path: Path, root: Path, user: dict[Path, bytes]) -> bool:
    """A file cnep left under `root` that is whole: named unchanged by its folder's record (as the command's it says),
    named by the manifest of a policy folder around it (or in a policy folder whose manifest the user overwrote: no
    way to tell), a record, or a temporary or lock file of a process that no longer runs."""
    name = path.name
    if path.is_symlink():
        return False
    if name == RECORD_FILE:
        return True
    if TEMPORARY.match(name) or is_lock_name(name):
        return not _held_by_a_live_process(path)
    entry = (read_record(path.parent) or {}).get(name)
    if entry is not None and is_recorded(path, entry.get("command")):
        return True
    manifests = [folder / MANIFEST_FILE for folder in _folders(path, root) if (folder / MANIFEST_FILE).is_file()]
    return any(m in user or in_manifest(m.parent, path) for m in manifests)


def _held_by_a_live_process(path: Path) -> bool:
    match = TEMPORARY.match(path.name)
    if match is not None:
        return pid_alive(int(match["pid"]))
    holder = re.search(rb'"pid": (\d+)', path.read_bytes()[:200])
    return holder is not None and pid_alive(int(holder[1]))


def _folders(path: Path, root: Path) -> list[Path]:
    return [p for p in path.parents if p.is_relative_to(root) and p != root]


def run_machine(
    world: World,
    base: Path,
    examples: int,
    steps: int,
    server: Preloaded | None = None,
    demo_runs: bool = False,
) -> Counter:
    """Run `examples` histories of up to `steps` steps each, seeded (the same histories every time); returns how
    many times each command ended each way ((command, "done" | "refused" | a signal's name) -> count)."""
    Ownership.world, Ownership.base, Ownership.server, Ownership.demo_runs = world, base, server, demo_runs
    Ownership.seen = Counter()
    stages, sim_stage._run_stages = sim_stage._run_stages, SimStages()
    try:
        _run(examples, steps)
    finally:
        sim_stage._run_stages = stages
    return Ownership.seen


def _run(examples: int, steps: int) -> None:
    run_state_machine_as_test(
        Ownership,
        settings=settings(
            max_examples=examples,
            stateful_step_count=steps,
            derandomize=True,
            database=None,
            deadline=None,
            suppress_health_check=list(HealthCheck),
        ),
    )
