"""The train stage's files while it runs: the work folder, the resumable state and the JSON-lines log.

A run holds the lock on OUT (`cnep.outputs`) and works in `.<OUT name>.partial/` beside OUT. Every
`save_every` steps, and when it is interrupted (Ctrl-C, SIGTERM), rank 0 writes there `state.pt`
(torch.save of the Trainer's state: model, optimiser, batch generators of every rank, step, best
weights, history; plus the run's identity) and `training_log.jsonl`, each atomically (temporary name +
rename), so a kill at any moment leaves the previous state readable. When training ends the
checkpoint files are written into the work folder, which then takes OUT's name (`publish`: an existing OUT is set
aside and checked again there, cnep.outputs.publish_folder)."""

from __future__ import annotations

import io
import json
import logging
import math
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path

import torch

from cnep.outputs import (
    NotOwned,
    Owns,
    foreign_files,
    output_lock,
    publish_folder,
    record_written,
    recorded_by,
    recover_set_aside,
    remove_owned,
    remove_stale_temporaries,
    write_output,
    writer,
)
from cnep.perception.errors import torch_load_problem
from cnep.pipeline.contract import output_folder, refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.ownership import not_written
from cnep.pipeline.train.constants import STATE_FILE

log = logging.getLogger(__name__)

STATE_VERSION = 1


def work_dir(out: Path) -> Path:
    """Folder of an unfinished run writing to `out`."""
    return out.parent / f".{out.name}.partial"


def owns() -> Owns:
    """What this run may replace or delete: the files its command recorded writing (`cnep.outputs.recorded_by`)."""
    return recorded_by(writer())


def prepare_work_dir(out: Path, resume: bool, force: bool, inputs: Sequence[Path], held: ExitStack) -> dict | None:
    """Claim OUT for this run and check OUT and the work folder; returns the saved state to resume from (None: start
    at step 0).

    Enters into `held`, for the run: the missing folders above OUT (removed again if the run fails before anything
    lands in them) and the lock on OUT (`cnep.outputs.output_lock`), which refuses a second run into OUT.
    """
    work = work_dir(out)
    refuse_inputs([out, work], inputs)
    held.enter_context(output_folder(out.parent))
    held.enter_context(output_lock(out))
    remove_stale_temporaries(work)
    recover_set_aside(out, owns())
    if out.exists() and not force and not not_written(out, owns()):  # else refuse_existing says why not --force
        raise PipelineError(
            f"{out} already exists; choose another --out, or add --force to replace it when the new run completes"
        )
    refuse_existing([out], force, "checkpoint")
    if not resume:
        if (work / STATE_FILE).is_file():
            raise PipelineError(
                f"{work} holds an unfinished run for {out}; add --resume to continue it, or delete "
                f"that folder to start again"
            )
        if work.exists():  # stopped before its first save: nothing in it can be resumed
            remove_work_dir(work)
            log.warning("%s: removed the work folder of a run that stopped before saving anything", work)
        work.mkdir()
        held.push(_remove_if_failed(out))
        return None
    if not work.is_dir():
        raise PipelineError(f"nothing to resume: {work} does not exist; run without --resume to start training")
    if not (work / STATE_FILE).is_file():
        log.warning("%s has no saved state yet (stopped before the first save): starting at step 0", work)
        return None
    return load_state(work / STATE_FILE)


def remove_work_dir(work: Path) -> None:
    """Delete a work folder, which holds only what this command recorded writing (refused, before anything goes,
    otherwise)."""
    foreign = foreign_files(work, owns())
    if foreign:
        raise PipelineError(
            f"{foreign[0]}: the work folder {work} holds a file that training did not write; move it away, or "
            f"choose another --out"
        )
    remove_owned(work, owns())
    work.rmdir()


def _remove_if_failed(out: Path):
    """An exit callback: when a fresh run fails (not when it is interrupted, which saves its state), its work folder
    goes unless it holds a saved state to resume from, so that nothing blocks the next run."""

    def remove(exc_type, exc, tb) -> bool:
        work = work_dir(out)
        failed = exc_type is not None and not issubclass(exc_type, KeyboardInterrupt)
        if failed and work.is_dir() and not (work / STATE_FILE).is_file():
            remove_work_dir(work)
        return False

    return remove


def save_state(path: Path, state: dict) -> None:
    """torch.save `state` to `path` atomically."""
    buffer = io.BytesIO()
    torch.save({"state_version": STATE_VERSION, **state}, buffer)
    write_output(path, buffer.getvalue())


def load_state(path: Path) -> dict:
    """The state saved by `save_state` (tensors on the CPU)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged file; all mean the same to the user
        raise PipelineError(
            f"{path}: cannot read the saved training state ({torch_load_problem(exc)}); delete {path.parent} and "
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
    write_output(path, ("\n".join(lines) + "\n" if lines else "").encode())


def publish(work: Path, out: Path) -> None:
    """Rename the finished work folder to `out` (an existing `out` is checked again and replaced only if the command
    recorded writing everything in it: cnep.outputs.publish_folder), then drop the resumable state."""
    try:
        publish_folder(work, out, owns())
    except NotOwned as exc:
        raise PipelineError(
            f"{exc.path}: --force replaces {out} only when `cnep {writer()}` recorded writing every file in it, and "
            f"this appeared in it while the run worked; cnep never deletes your own files: {out} is kept as it was "
            f"and the new checkpoint waits in {work}; move the file away, then run the same command with --resume "
            f"to put it in place"
        ) from None
    (out / STATE_FILE).unlink(missing_ok=True)
    record_written([], forget=[out / STATE_FILE])


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
