"""The folder a `cnep sim TASK --out OUT` run works in, `.OUT.partial` beside OUT, and its record of the stages it
finished, so that a stopped run resumes where it stopped.

    with partial_run(out, settings, total, force) as run:  # the lock on OUT held; OUT a new or empty folder
        made = run.stage("generate", 1, make)  # finished before: its recorded result; else run, timed, recorded
        ...
        run.publish(out, summary)  # summary.json written, the folder renamed to OUT

STAGES_FILE in the folder (written as the command's output, cnep.outputs) names the run's `settings` (what makes the
run: its options but --out, -q and --force), each finished stage in order with its wall time (s) and result (what
the summary takes from it: JSON), and `files`: every file of the folder when the last stage finished, by its path
relative to the folder, with its size (bytes) and sha256. A file is listed only if it is the command's: named
unchanged by its folder's record (cnep.outputs.record) or, in a policy folder, by its manifest
(pipeline.export.stage.in_manifest).

A stage that runs long in parts (the closed loop, a policy at a time) records each finished part under PARTS_DIR
(`PartialRun.part`: its result and its files with their sizes and sha256); a resumed run keeps the parts of the
stage that was stopped whose files are unchanged (`PartialRun.kept_parts`), and a finished stage's parts go.

A run into OUT with the same settings resumes the folder: every listed file must be there unchanged; what else the
command owns in it (the leftovers of the stage that was stopped, the stale work folders of its processes) goes, and a
file it does not own (a user's) is refused with one line, never deleted. A run with other settings, or whose listed
files changed, is refused with one line. `force` discards the folder's files that the command owns (a user's stay,
and are refused then) and starts over. A run that fails before its first stage finishes leaves nothing; one stopped
later keeps the folder and says in one line how to resume.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cnep.outputs import (
    TEMPORARY,
    NotOwned,
    Owns,
    is_recorded,
    is_stale_temporary,
    naming,
    output_lock,
    publish_folder,
    recover_set_aside,
    remove_owned,
    write_output,
    writer,
)
from cnep.outputs.record import RECORD_FILE, file_entry
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_file_as_folder
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.export.stage import in_manifest
from cnep.pipeline.folders import said_of_output
from cnep.pipeline.progress import StageClock
from cnep.runtime.constants import MANIFEST_FILE
from cnep.runtime.jsonfile import read_json

log = logging.getLogger(__name__)

STAGES_FILE = "stages.json"
SUMMARY_FILE = "summary.json"
STAGES_VERSION = 1
PARTS_DIR = "parts"  # PARTS_DIR/<stage>/<part>.json: the finished parts of the stage that runs


def partial_folder(out: Path) -> Path:
    """The folder a run into `out` works in, beside it."""
    return out.parent / f".{out.name}.partial"


def owns_partial(command: str) -> Owns:
    """What of a partial folder `command` owns: a file its folder's record names unchanged as `command`'s, or a file
    an exported policy folder's manifest names unchanged (a policy folder's record: pipeline.export.stage)."""

    def owns(root: Path, path: Path) -> bool:
        if is_recorded(path, command):
            return True
        folders = [p for p in path.parents if p.is_relative_to(root) and p != root]
        return any((f / MANIFEST_FILE).is_file() and in_manifest(f, path) for f in folders)

    return owns


@dataclass
class PartialRun:
    """A run's partial folder `work` (module docstring): the settings that make the run, the stages finished (name ->
    {"seconds", "result"}, in order) and the files listed when the last finished."""

    work: Path
    settings: dict
    total: int  # the run's stages, for the log's `[n/total]`
    finished: dict[str, dict] = field(default_factory=dict)
    files: dict[str, dict] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)  # every stage's wall time (s); its start while it runs
    parts: dict[str, dict[str, Any]] = field(default_factory=dict)  # stage -> part -> result, kept from a stopped run
    # While a stage runs: what it enters here (cnep.outputs.signals_held, from the moment it changes a finished
    # stage's files) stays held until the stage is recorded as finished.
    held: contextlib.ExitStack | None = None

    def done(self, name: str) -> bool:
        """Whether the stage `name` finished (in this run or one before)."""
        return name in self.finished

    def stage(self, name: str, number: int, make: Callable[[], Any]) -> Any:
        """The stage `name` (the `number`th): its recorded result where it finished before, else `make()` timed, its
        files listed and its result (JSON, as read back) recorded."""
        if self.done(name):
            log.info("[%d/%d] %s: finished before, kept", number, self.total, name)
            self.seconds[name] = self.finished[name]["seconds"]
            return self.finished[name]["result"]
        with contextlib.ExitStack() as self.held:
            with StageClock(self.seconds, self.total, log)(name, number):
                result = json.loads(json.dumps(make()))
            self.finished[name] = {"seconds": self.seconds[name], "result": result}
            self._forget_parts(name)
            self.files = listed_files(self.work, self.files)
            self._save()
        self.held = None
        return result

    def kept_parts(self, stage: str) -> dict[str, Any]:
        """The parts of the stage `stage` a stopped run finished, unchanged since: part -> its result."""
        return dict(self.parts.get(stage, {}))

    def part(self, stage: str, name: str, result: Any, files: list[Path]) -> None:
        """Record the part `name` of the running stage `stage` as finished: its result (JSON) and its `files` (under
        the folder), which a resumed run keeps with it."""
        entries = {}
        for path in files:
            entry = file_entry(path, "")
            entries[path.relative_to(self.work).as_posix()] = {"size": entry["size"], "sha256": entry["sha256"]}
        folder = self.work / PARTS_DIR / stage.replace(" ", "-")
        folder.mkdir(parents=True, exist_ok=True)
        record = {"stage": stage, "result": result, "files": entries}
        write_output(folder / f"{name}.json", json.dumps(record).encode())

    def _forget_parts(self, stage: str) -> None:
        """The parts of `stage`, finished now, go (the stage's record holds them all)."""
        folder = self.work / PARTS_DIR / stage.replace(" ", "-")
        if folder.is_dir():
            remove_owned(folder, owns_partial(writer()))
            for empty in (folder, folder.parent):
                with contextlib.suppress(OSError):
                    empty.rmdir()

    def publish(self, out: Path, summary: dict) -> None:
        """Write the summary into the folder and rename the folder to `out` (cnep.outputs.publish_folder: an empty
        `out` is replaced; a file that appeared in it meanwhile keeps it, and this folder, as they are)."""
        write_output(self.work / SUMMARY_FILE, json.dumps(summary, indent=1).encode())
        publish_folder(self.work, out, owns_partial(writer()))

    def resume_line(self, out: Path) -> str:
        """What the user can do now that the run stopped with its finished stages kept."""
        kept = ", ".join(self.finished)
        return (
            f"the finished stages ({kept}) are kept in {self.work}: run the same command again to resume, or add "
            f"--force to start over"
        )

    def _save(self) -> None:
        body = {"format_version": STAGES_VERSION, "settings": self.settings, "stages": self.finished}
        write_output(self.work / STAGES_FILE, json.dumps({**body, "files": self.files}, indent=1).encode())


def listed_files(work: Path, before: dict[str, dict]) -> dict[str, dict]:
    """Every file under `work` the command owns (owns_partial), by relative path: {"size", "sha256", "mtime_ns"};
    a file listed in `before` with the same size and modification time keeps its entry (not hashed again)."""
    owns, listed = owns_partial(writer()), {}
    for path in sorted(work.rglob("*")):
        rel = path.relative_to(work).as_posix()
        if path.is_symlink() or not path.is_file() or path.name == RECORD_FILE or path == work / STAGES_FILE:
            continue
        stat, old = path.stat(), before.get(rel)
        if old is not None and (old["size"], old["mtime_ns"]) == (stat.st_size, stat.st_mtime_ns):
            listed[rel] = old
        elif owns(work, path):
            entry = file_entry(path, "")
            listed[rel] = {"size": entry["size"], "sha256": entry["sha256"], "mtime_ns": stat.st_mtime_ns}
    return listed


@contextlib.contextmanager
def partial_run(out: Path, settings: dict, total: int, force: bool) -> Iterator[PartialRun]:
    """The run's partial folder for `out` (module docstring), holding the lock on `out`: resumed where it holds a run
    of `settings`, else made; `out` must be missing or an empty folder. On failure the folder is kept with its
    finished stages (the one line of an interruption says how to resume) or, before any stage finished, removed."""
    work = partial_folder(out)
    owns = owns_partial(writer())
    with output_folder(out.parent), output_lock(out):
        check_writable_folder(out.parent)
        recover_set_aside(out, owns)
        refuse_unless_new(out)
        run = open_partial(work, settings, total, force)
        try:
            with naming(out), said_of_output(work, out):  # a full disk: said of OUT, not of the partial folder
                yield run
        except BaseException as exc:
            kept = bool(run.finished)
            if not kept:
                discard_partial(work, owns)
            if isinstance(exc, NotOwned):
                resumes = f" (it resumes from {work})" if kept else ""
                raise PipelineError(
                    f"{exc.path}: this appeared in {out} (--out) while `cnep {writer()}` ran, and a command replaces "
                    f"a folder only when it wrote every file in it; cnep never deletes your own files: {out} is kept "
                    f"as it was; move the file away and run the command again{resumes}"
                ) from None
            if not kept:
                raise
            if isinstance(exc, KeyboardInterrupt):
                raise type(exc)(run.resume_line(out)) from None
            if isinstance(exc, PipelineError):
                raise PipelineError(f"{exc} ({run.resume_line(out)})") from None
            if isinstance(exc, OSError) and exc.strerror:  # its line: the file, the problem (and here what was kept)
                raise OSError(exc.errno, f"{exc.strerror} ({run.resume_line(out)})", exc.filename) from None
            log.warning("%s", run.resume_line(out))
            raise


def refuse_unless_new(out: Path) -> None:
    """PipelineError unless `out` is missing or an empty folder: the command writes into a new folder only."""
    refuse_file_as_folder(out)
    if out.is_dir() and any(out.iterdir()):
        raise PipelineError(f"{out}: `cnep {writer()} --out` writes into a new folder and this one is not empty")


def open_partial(work: Path, settings: dict, total: int, force: bool) -> PartialRun:
    """The partial folder `work` made, or resumed (its finished stages' files checked, everything else the command
    owns in it removed), or with `force` emptied of what the command owns and started over; PipelineError where it
    holds another run (without `force`), or files the command does not own."""
    settings = json.loads(json.dumps(settings))
    if not work.is_dir() or work.is_symlink():
        if os.path.lexists(work):
            raise PipelineError(f"{work}: not a folder; cnep sim works in it beside --out: move it away")
        work.mkdir()
        return PartialRun(work, settings, total)
    owns = owns_partial(writer())
    saved = read_stages(work / STAGES_FILE)
    problem = why_not_resumable(work, saved, settings)
    if problem and not force:
        raise PipelineError(f"{problem}; add --force to discard it (only the files that run wrote go) and start over")
    if force or saved is None:
        if saved is not None:
            log.warning("%s: discarding the stopped run in it (--force)", work)
        saved = {"stages": {}, "files": {}}
    kept = {work / rel for rel in saved["files"]} | ({work / STAGES_FILE} if saved["stages"] else set())
    parts = [] if force else finished_parts(work, owns)
    kept |= {path for part in parts for path in (part.path, *part.files)}
    remove_stale_work_folders(work)
    left = remove_owned(work, lambda root, path: path not in kept and owns(root, path))  # records stay with kept files
    foreign = [path for path in left if path not in kept]
    if foreign:
        raise PipelineError(
            f"{foreign[0]}: the folder {work}, where `cnep {writer()}` works, holds this, which it did not write; "
            f"cnep never deletes your own files: move it away and run the command again"
        )
    if saved["stages"]:
        log.info("%s: resuming after the stages %s", work, ", ".join(saved["stages"]))
    kept_parts: dict[str, dict[str, Any]] = {}
    for part in parts:
        kept_parts.setdefault(part.stage, {})[part.name] = part.result
    return PartialRun(work, settings, total, dict(saved["stages"]), dict(saved["files"]), parts=kept_parts)


@dataclass(frozen=True)
class Part:
    """A finished part of a stage (`PartialRun.part`): its record `path`, its stage and name, its result and files."""

    path: Path
    stage: str
    name: str
    result: Any
    files: tuple[Path, ...]


def finished_parts(work: Path, owns: Owns) -> list[Part]:
    """The parts recorded under `work`/PARTS_DIR that are intact; a record the command does not own, that cannot be
    read, or whose files changed is left out (its files then go as the stopped stage's leftovers)."""
    found = []
    for path in sorted((work / PARTS_DIR).glob("*/*.json")):
        if path.is_symlink() or not path.is_file() or not owns(work, path):
            continue
        try:
            data = read_json(path)
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or not isinstance(data.get("files"), dict) or "result" not in data:
            continue
        files = {work / rel: entry for rel, entry in data["files"].items()}
        if all(isinstance(e, dict) and unchanged(f, e) and owns(work, f) for f, e in files.items()):
            found.append(Part(path, str(data.get("stage")), path.stem, data["result"], tuple(files)))
    return found


def unchanged(path: Path, entry: dict) -> bool:
    """Whether `path` is a regular file of the size and sha256 `entry` records."""
    if path.is_symlink() or not path.is_file() or path.stat().st_size != entry.get("size"):
        return False
    return file_entry(path, "")["sha256"] == entry.get("sha256")


def read_stages(path: Path) -> dict | None:
    """The STAGES_FILE at `path` ({"settings", "stages", "files"}); None where there is none, or it is not one of
    this version (read within cnep's JSON bound)."""
    try:
        if not path.is_file() or path.is_symlink():  # a pipe planted there would make open() wait for a writer
            return None
        data = read_json(path)
    except (OSError, ValueError):  # unreadable: no record, the folder then holds no run to resume
        return None
    keys = ("settings", "stages", "files")
    if not isinstance(data, dict) or data.get("format_version") != STAGES_VERSION:
        return None
    if not all(isinstance(data.get(k), dict) for k in keys):
        return None
    return {k: data[k] for k in keys}


def why_not_resumable(work: Path, saved: dict | None, settings: dict) -> str:
    """Why the partial folder `work` cannot be resumed by a run of `settings` (empty: it can, or holds no run)."""
    if saved is None:
        return ""
    if saved["settings"] != settings:
        differ = [name for name in settings if saved["settings"].get(name) != settings[name]]
        given = ", ".join(f"{name} {saved['settings'].get(name)!r}" for name in differ[:3])
        return f"{work}: holds a run stopped with other settings ({given}); give the same to resume it"
    for rel, entry in saved["files"].items():
        if not unchanged(work / rel, entry):
            return (
                f"{work / rel}: changed or missing since the stage that wrote it finished, so {work} cannot be resumed"
            )
    return ""


def remove_stale_work_folders(work: Path) -> None:
    """Remove the work folders (`.NAME.<pid>-<hex>.tmp`) that stopped processes of a run left under `work`: made new
    and unique to a process, they hold only what it wrote (cnep.outputs.temporary_path)."""
    for folder, dirs, _ in os.walk(work):
        for name in list(dirs):
            path = Path(folder) / name
            if TEMPORARY.match(name) and not path.is_symlink() and is_stale_temporary(path):
                shutil.rmtree(path, ignore_errors=True)
                dirs.remove(name)


def discard_partial(work: Path, owns: Owns) -> None:
    """Remove the partial folder `work` of a run that finished no stage: what the command owns goes, and the folder
    with it; a file it does not own stays, with a warning."""
    remove_stale_work_folders(work)
    left = remove_owned(work, owns)
    with contextlib.suppress(OSError):
        work.rmdir()
    if left:
        log.warning("%s: kept, it holds %s, which the command did not write", work, left[0])
