"""The contract every `cnep` subcommand keeps, in one place (docs/reference/cli-contract.md explains it for users).

    exit 0     done
    exit 2     the user can fix it: a missing, damaged or misfit input, an existing output without
               --force, a folder that cannot be written, a `--keep-going` run that skipped inputs
    exit 130   interrupted (Ctrl-C, SIGINT)
    exit 143   terminated (SIGTERM: `kill`, `docker stop`, systemd, Kubernetes, Slurm preemption)
    exit 1     a bug in cnep (anything else); the line says so, `-v` prints the traceback

- Errors are one line on stderr, `cnep <cmd>: error: <path>: <problem>; <fix>` (`error_line`); no
  traceback for anything a user can cause, unless `-v` asks for it (`run_command`).
- Outputs are never overwritten without `--force` (`refuse_existing`): ingest, to-lerobot, extract, repair,
  replay, train, export, run, evaluate and demo alike; `--force` replaces only what a cnep command recorded
  writing (`pipeline.ownership`, `cnep.outputs.record`), and never an input or a folder holding one
  (`refuse_inputs`). Inputs are never written.
- One run at a time per output: each command holds the output's lock for the run (`cnep.outputs`).
- Nothing is left behind on failure: files are written to a temporary name and renamed when complete,
  and a folder a command created is removed again if it fails or is interrupted before anything
  landed in it (`output_folder`).
- ingest and extract take `--keep-going`: a bad input is skipped, the others are written, and the run
  ends with exit 2 and one line naming what was skipped (`raise_if_skipped`).
- Files are written with the user's umask (0666 less the umask), like any other tool's.
- A reader that stops reading (`cnep inspect A B | head -1`) ends the command quietly with exit 0.
- SIGTERM is handled like Ctrl-C (`Terminated` is a KeyboardInterrupt), so every clean-up that runs on
  Ctrl-C runs on it too; a block that must end at a safe point (a training step) defers both
  (`deferred_interrupts`). Both are handled from the first line of the `cnep` command (`handle_signals`) to
  its last: once the command has finished, a signal during the interpreter's exit ends it at once, with one
  line saying its outputs are complete.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from cnep.outputs import RECORD_FILE, Owns, recorded_by, writer
from cnep.pipeline.errors import PipelineError, loaded_user_errors
from cnep.pipeline.ownership import not_written

EXIT_OK = 0
EXIT_BUG = 1
EXIT_USER = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143, what a shell reports for a process that SIGTERM ended

# errno -> what the user can do about an OSError on that path.
_OS_FIXES = {
    errno.EACCES: "choose a path you can write to, or change its permissions",
    errno.EPERM: "choose a path you can write to, or change its permissions",
    errno.EROFS: "the file system is read-only; choose a path on another one",
    errno.ENOSPC: "free some disk space, or choose a path on another disk",
    errno.EDQUOT: "your disk quota is used up; free some space, or choose a path on another disk",
    errno.EFBIG: "the file is larger than this file system allows; choose a path on another one",
    errno.EIO: "the disk reported an input/output error; check it, or choose a path on another disk",
    errno.ENOENT: "check the path",
    errno.EEXIST: "choose another path, or remove it",
    errno.EISDIR: "give a file path, not a folder",
    errno.ENOTDIR: "a part of the path is a file, not a folder; check the path",
}


def error_line(command: str, exc: BaseException) -> str:
    """The one line printed for a user error: `cnep <cmd>: error: <path>: <problem>; <fix>`."""
    if isinstance(exc, OSError) and not isinstance(exc, BrokenPipeError):
        where = f"{exc.filename}: " if exc.filename else ""
        fix = _OS_FIXES.get(exc.errno or 0, "check the path and its permissions")
        return f"cnep {command}: error: {where}{exc.strerror or exc}; {fix}"
    return f"cnep {command}: error: {' '.join(str(exc).split())}"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C raises KeyboardInterrupt, so that whatever cleans up after Ctrl-C does so too."""


def interruption(signum: int, then: str = "") -> KeyboardInterrupt:
    """The exception that signal `signum` (SIGINT or SIGTERM) raises; `then`, if given, is what the user can do
    now, said in the one line instead of the default."""
    return Terminated(then) if signum == signal.SIGTERM else KeyboardInterrupt(then)


_finished: list[tuple[str, int]] = []  # (command, exit status) once the command has finished: the process is exiting


def _raise_interruption(signum: int, frame: object) -> None:
    if _finished:  # the work is done, the interpreter is tearing down (atexit, threads): end now, with a line
        _end_at_once(signum, *_finished[-1])
    raise interruption(signum)


def _end_at_once(signum: int, command: str, status: int) -> None:
    """A signal once the command has finished: one line (unless its failure's line is out already) and exit now."""
    how = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        if status == EXIT_OK:
            print(f"cnep {command}: {how} while exiting; it had finished, its outputs are complete", file=sys.stderr)
        sys.stderr.flush()
    os._exit(EXIT_TERMINATED if signum == signal.SIGTERM else EXIT_INTERRUPTED)


def handle_signals() -> Callable[[str, int], None]:
    """SIGINT and SIGTERM raise `interruption` from now on (the first line of the `cnep` command), in the main thread;
    returns `finished(command, status)`, which makes them end the process at once from then on (its last lines)."""
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, _raise_interruption)
    _finished.clear()
    return lambda command, status: _finished.append((command, status))


def interrupted_line(command: str, exc: KeyboardInterrupt) -> int:
    """Print the one line of an interrupted command (SIGINT or SIGTERM: `exc`); returns its exit status."""
    how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
    then = str(exc) or "nothing half-written was kept, run the command again to finish"  # a stage may say more
    print(f"{f'cnep {command}'.strip()}: {how}; {then}", file=sys.stderr)
    return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED


@contextlib.contextmanager
def _signals_raise(handler=_raise_interruption) -> Iterator[None]:
    """SIGTERM (and SIGINT) call `handler` in the block; only the main thread can install handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {signum: signal.signal(signum, handler) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, previous in saved.items():
            signal.signal(signum, previous)


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[Callable[[], int | None]]:
    """Record SIGINT and SIGTERM in the block instead of raising them; yields a poll of the signal received.

    The block polls at its safe points (between training steps) and ends itself with `interruption(signum)`.
    A second signal raises at once, so a block stuck between safe points can still be stopped.
    """
    received: list[int] = []

    def record(signum: int, frame: object) -> None:
        if received:
            raise interruption(signum)
        received.append(signum)

    with _signals_raise(record):
        yield lambda: received[0] if received else None


def run_command(command: str, run: Callable[[], int | None], verbose: bool = False) -> int:
    """Run one subcommand under the contract; returns its exit status."""
    try:
        with _signals_raise():
            return int(run() or EXIT_OK)
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_OK
    except KeyboardInterrupt as exc:
        _discard_bars()
        return interrupted_line(command, exc)
    except Exception as exc:  # noqa: BLE001 - the contract: every failure is one line and an exit status
        _discard_bars()
        user = isinstance(exc, (*loaded_user_errors(), OSError))
        if verbose:
            traceback.print_exc()
        if user:
            print(error_line(command, exc), file=sys.stderr)
            return EXIT_USER
        print(
            f"cnep {command}: error: internal error ({type(exc).__name__}: {' '.join(str(exc).split())}); this is "
            f"a bug in cnep: run again with -v for the traceback and report it",
            file=sys.stderr,
        )
        return EXIT_BUG


def _discard_bars() -> None:
    """Progress bars still open when a command fails go without a last line (only if a stage made one)."""
    if "cnep.pipeline.progress" in sys.modules:
        sys.modules["cnep.pipeline.progress"].discard_bars()


def _stdout_to_devnull() -> None:
    """After a broken pipe: later writes (and the interpreter's final flush) go nowhere instead of failing."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())


def refuse_existing(
    paths: Sequence[Path], force: bool, what: str = "output", why: str = "", owns: Owns | None = None
) -> None:
    """Raise PipelineError if any of `paths` exists and `force` is not set (naming the first and the count).

    With `force`, an existing path must be the command's to replace (`pipeline.ownership.not_written`): `owns` says
    what it owns, by default the files the command writing now (`cnep.outputs.writing_as`) recorded writing; the line
    names the first file that is not. Before a stage says which command it is, only existence is checked (the stage
    checks again). `why` (e.g. " and was made from other weights") is said after "already exists".
    """
    existing = [Path(p) for p in paths if os.path.lexists(p)]
    if not existing:
        return
    command = writer()
    who = f"`cnep {command}`" if command else "this command"
    owns = recorded_by(command) if owns is None and command is not None else owns
    if not force:
        foreign = not_written(existing[0], owns) if owns is not None else []
        if foreign:  # --force would refuse it too: say so, and suggest only what works
            raise PipelineError(
                f"{existing[0]}: the {what} already exists{why}, and --force would not replace it either "
                f"({foreign[0]} is not a file {who} recorded writing); choose another output, or move it away"
            )
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise PipelineError(
            f"{existing[0]}: the {what} already exists{why}{more}; add --force to replace it, or choose another output"
        )
    if owns is None:
        return
    for path in existing:
        foreign = not_written(path, owns)
        if not foreign:
            continue
        first, more = foreign[0], f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        if path.is_dir():
            said = f"replaces the folder {path} only when {who} recorded writing every file in it"
        else:
            said = f"replaces only what {who} recorded writing (its folder's {RECORD_FILE})"
        raise PipelineError(
            f"{first}: --force {said}, and this is a file of yours or another command's output{more}; cnep never "
            f"deletes your own files: move it away, or choose another output"
        )


def refuse_inputs(
    outputs: Sequence[Path],
    inputs: Sequence[Path],
    option: str = "--out",
    what: str = "this output",
    whole: bool = True,
) -> None:
    """Raise PipelineError if an output is an input or is inside one (a folder given as input: a checkpoint, a folder
    of recordings): no command writes inside what it reads. With `whole` (a file, or a folder replaced as a whole),
    an output that holds an input is refused too; a folder only written into (`whole` False) may hold one."""
    resolved = [(Path(i), Path(i).resolve()) for i in inputs]
    for out in map(Path, outputs):
        target = out.resolve()
        for given, source in resolved:
            if source == target or (whole and source.is_relative_to(target)):
                how = "is" if source == target else "holds"
                raise PipelineError(
                    f"{out}: {what} {how} the input {given}, and cnep never replaces or deletes its inputs; "
                    f"choose another {option}"
                )
            if target.is_relative_to(source):
                raise PipelineError(
                    f"{out}: {what} is inside the input {given}, and cnep never writes inside its inputs; choose "
                    f"another {option}, outside it"
                )


def refuse_file_as_folder(folder: Path, option: str = "--out") -> None:
    """Raise PipelineError if `folder`, meant to be an output folder, is an existing file."""
    if folder.exists() and not folder.is_dir():
        raise PipelineError(f"{folder}: is a file, but {option} names a folder to write into; give a folder path")


@contextlib.contextmanager
def output_folder(folder: Path, option: str = "--out") -> Iterator[Path]:
    """Create `folder` (and its missing parents) for the block; on failure remove every folder made since, if empty.

    Folders made inside it during the block (nested outputs) count too: a failed or interrupted run
    leaves no empty folders behind, while files already complete stay (they are never half-written).
    """
    folder = Path(folder)
    refuse_file_as_folder(folder, option)
    made = [p for p in (folder, *folder.parents) if not p.exists()]  # deepest first
    before = {Path(root) for root, _, _ in os.walk(folder)} if folder.is_dir() else set()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PipelineError(
            f"{folder}: cannot create the output folder ({exc.strerror}); "
            f"{_OS_FIXES.get(exc.errno or 0, 'check the path')}"
        ) from None
    try:
        yield folder
    except BaseException:
        inside = [Path(root) for root, _, _ in os.walk(folder, topdown=False)]
        for path in [*(p for p in inside if p not in before and p != folder), *made]:
            with contextlib.suppress(OSError):
                path.rmdir()  # only empty folders go
        raise


def check_writable_folder(folder: Path) -> None:
    """Raise PipelineError unless files can be created in `folder` (an existing folder)."""
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PipelineError(
            f"{folder}: cannot write in this folder (permission denied); choose an output folder you can write to"
        )


def raise_if_skipped(skipped: Sequence[str], total: int, verb: str) -> None:
    """End a `--keep-going` run: PipelineError with the skipped inputs' errors (each names its file), if any."""
    if not skipped:
        return
    shown = "; ".join(skipped[:3])
    more = f"; and {len(skipped) - 3} more (see the warnings above)" if len(skipped) > 3 else ""
    raise PipelineError(
        f"{len(skipped)} of {total} input(s) skipped, the other {total - len(skipped)} {verb}: "
        f"{shown}{more}; fix or remove the skipped inputs and run again for them"
    )
