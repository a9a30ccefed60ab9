"""Run `cnep ARGS` with one function paused at its N-th call, so that a test can kill the process exactly there.

    python -m tests.pipeline.fault_driver cnep.pipeline.train.stage:StageTrainer.train_step 26 GO -- -q train ...

When the N-th call begins it prints `paused <pid>` and waits until the file GO exists (a test sends its
signal first, then creates GO to let a deferred signal take effect), then makes the call.
"""

from __future__ import annotations

import importlib
import os
import sys
import time
from pathlib import Path


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


if __name__ == "__main__":
    target, hit, go, separator, *argv = sys.argv[1:]
    assert separator == "--", sys.argv
    pause_at(target, int(hit), Path(go))
    from cnep.pipeline.cli.main import main

    sys.exit(main(argv))
