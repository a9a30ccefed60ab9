"""Run `cnep ARGS` with one function paused at its N-th call, so that a test can kill the process exactly there;
and what the fault tests and the soak (benchmarks/soak_faults.py) look at in an output folder.

    python -m tests.pipeline.fault_driver cnep.pipeline.train.stage:StageTrainer.train_step 26 GO -- -q train ...

When the N-th call begins it prints `paused <pid>` and waits until the file GO exists (a test sends its
signal first, then creates GO to let a deferred signal take effect), then makes the call. The target `atexit`
pauses in an exit handler instead, once the command has finished.
"""

from __future__ import annotations

import atexit
import importlib
import os
import sys
import time
from pathlib import Path

from cnep.outputs import RECORD_FILE, TEMPORARY, is_lock_name


def files(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative path -> bytes), cnep's temporary and lock files and records left out."""
    if not folder.exists():
        return {}
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not TEMPORARY.match(p.name) and not is_lock_name(p.name) and p.name != RECORD_FILE
    }


def stray(folder: Path) -> list[str]:
    """cnep's temporary and lock files anywhere under `folder` (relative paths)."""
    if not folder.exists():
        return []
    found = [p for p in folder.rglob("*") if p.is_file() and (TEMPORARY.match(p.name) or is_lock_name(p.name))]
    return sorted(str(p.relative_to(folder)) for p in found)


def pause_at(target: str, hit: int, go: Path) -> None:
    """Replace `module:Attr.name` by a wrapper that pauses at its `hit`-th call."""
    module, _, attr = target.partition(":")
    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for part in path:
        owner = getattr(owner, part)
    original = getattr(owner, name)
    calls = [0]

    def paused(*args, **kwargs):
        calls[0] += 1
        if calls[0] == hit:
            print(f"paused {os.getpid()}", flush=True)
            while not go.exists():
                time.sleep(0.02)
        return original(*args, **kwargs)

    setattr(owner, name, paused)


def pause_at_exit(hit: int, go: Path) -> None:
    """An exit handler that pauses like `pause_at` (`hit` is ignored: it runs once)."""
    print(f"paused {os.getpid()}", flush=True)
    while not go.exists():
        time.sleep(0.02)


if __name__ == "__main__":
    target, hit, go, separator, *argv = sys.argv[1:]
    assert separator == "--", sys.argv
    if target == "atexit":  # a slow exit: the interpreter's exit handlers, after the command has finished
        atexit.register(pause_at_exit, int(hit), Path(go))
    else:
        pause_at(target, int(hit), Path(go))
    from cnep.pipeline.cli.main import main

    sys.argv = ["cnep", *argv]
    sys.exit(main())  # as the `cnep` command runs it: argv from the command line
