"""The train stage's files while it runs: the work folder, the resumable state and the JSON-lines log.

A run works in `.<OUT name>.partial/` beside OUT. Every `save_every` steps rank 0 writes there
`state.pt` (torch.save of the Trainer's state: model, optimiser, batch generators of every rank, step,
best weights, history; plus the run's identity) and `training_log.jsonl`, each atomically (temporary
name + rename), so a kill at any moment leaves the previous state readable. When training ends the
checkpoint files are written into the work folder, which is then renamed to OUT.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import shutil
from pathlib import Path

import torch

from cnep.outputs import write_atomically
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.constants import STATE_FILE

log = logging.getLogger(__name__)

STATE_VERSION = 1


def work_dir(out: Path) -> Path:
    """Folder of an unfinished run writing to `out`."""
    return out.parent / f".{out.name}.partial"


def prepare_work_dir(out: Path, resume: bool, force: bool) -> dict | None:
    """Check OUT and the work folder for a run; returns the saved state to resume from (None: start at step 0)."""
    work = work_dir(out)
    if out.exists() and not force:
        raise PipelineError(
            f"{out} already exists; choose another --out, or add --force to replace it when the new run completes"
        )
    if not resume:
        if work.exists():
            raise PipelineError(
                f"{work} holds an unfinished run for {out}; add --resume to continue it, or delete "
                f"that folder to start again"
            )
        work.mkdir(parents=True)
        return None
    if not work.is_dir():
        raise PipelineError(f"nothing to resume: {work} does not exist; run without --resume to start training")
    if not (work / STATE_FILE).is_file():
        log.warning("%s has no saved state yet (stopped before the first save): starting at step 0", work)
        return None
    return load_state(work / STATE_FILE)


def save_state(path: Path, state: dict) -> None:
    """torch.save `state` to `path` atomically."""
    buffer = io.BytesIO()
    torch.save({"state_version": STATE_VERSION, **state}, buffer)
    write_atomically(path, buffer.getvalue())


def load_state(path: Path) -> dict:
    """The state saved by `save_state` (tensors on the CPU)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged file; all mean the same to the user
        raise PipelineError(
            f"{path}: cannot read the saved training state ({exc}); delete {path.parent} and "
            f"train again without --resume"
        ) from None
    if state.get("state_version") != STATE_VERSION:
        raise PipelineError(
            f"{path}: training state version {state.get('state_version')!r} is not "
            f"{STATE_VERSION}; delete {path.parent} and train again without --resume"
        )
    return state


def check_same_run(saved: dict, current: dict, path: Path) -> None:
    """Refuse to resume a run whose identity (data, layout, model, training settings, processes) changed."""
    changed = _changed_keys(saved, current)
    if changed:
        details = "; ".join(
            f"{key}: saved {_short(a)}, now {_short(b)}"
            for key in changed
            for a, b in [_differing(saved.get(key), current.get(key))]
        )
        raise PipelineError(
            f"{path}: cannot resume, the run was started with other settings ({details}); use the "
            f"same inputs and options, or delete {path.parent} to start again"
        )


def write_log(path: Path, history: list[dict]) -> None:
    """The validation history as JSON lines (one object per validation), atomically."""
    lines = [json.dumps({k: _jsonable(v) for k, v in entry.items()}) for entry in history]
    write_atomically(path, ("\n".join(lines) + "\n" if lines else "").encode())


def publish(work: Path, out: Path) -> None:
    """Rename the finished work folder to `out` (replacing an existing `out`), then drop the resumable state."""
    old = out.parent / f".{out.name}.replaced"
    if out.exists():
        out.rename(old)
    work.rename(out)
    (out / STATE_FILE).unlink(missing_ok=True)
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old)
    elif os.path.lexists(old):  # --force replaced a file
        old.unlink()


def _jsonable(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _changed_keys(saved: dict, current: dict) -> list:
    return sorted(key for key in saved.keys() | current.keys() if saved.get(key) != current.get(key))


def _differing(saved, current) -> tuple:
    """Two settings with the entries they share dropped when both are dicts, so the difference shows."""
    if isinstance(saved, dict) and isinstance(current, dict):
        keys = _changed_keys(saved, current)
        return {k: saved[k] for k in keys if k in saved}, {k: current[k] for k in keys if k in current}
    return saved, current


def _short(value, limit: int = 80) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= limit else text[:limit] + "..."
