"""The replay stage: trajectory files through a trained CNEP, step by step, into Rerun.

    replay(checkpoint_dir, [recording.mcap, ...], "out.rrd") -> [the .rrd files written]

The jobs, one module each: `conditioning` steps an online conditioner through each recording (the
gate, the active expert, the switches, the predicted path per step); `rerun_log` logs them to Rerun
next to the camera frames and the end-effector pose (where things go: `viewer`); `decisions` writes
and reads the decisions file. This module checks the inputs and orchestrates:

- Always writes the `.rrd` (under the lock of `out`; every file under a temporary name, all renamed
  into place together when the replay completes: cnep.outputs). A
  live viewer gets the same stream only when one answers at `connect` (a TCP probe first; a warning
  when none does, never a hang). Several recordings become one file each beside `out.rrd`
  (`out-01-<folder>-<name>.rrd`, ...: a file of one recording opens on it), or with `merge` several
  Rerun recordings of one application in `out.rrd` (merged with the `rerun rrd merge` of rerun-sdk).
- The decisions (gate and expert per step, switches, each expert's share of the steps) are written
  next to the .rrd as `<name>.experts.json` (`read_decisions`).
- With `events_dir`, a copy of each recording with the decisions on `/events` (one Event per span of
  an active expert) is written there, so Foxglove shows them (the input is never modified).

Which recording columns the model sees is the checkpoint's (pipeline.train.checkpoint); a recording
that does not fit them is refused before anything is written.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shlex
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.models import CNEP, ConditioningPolicy
from cnep.models.threads import torch_threads
from cnep.outputs import Staging, output_file, output_lock, staged, writing_as
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import TRAJECTORIES, existing_files
from cnep.pipeline.replay.conditioning import DEFAULT_PREDICTION_POINTS, decide
from cnep.pipeline.replay.decisions import decision_events, decisions_path, summarise
from cnep.pipeline.replay.rerun_log import (
    DEFAULT_VIEWER_URL,
    merge_rrd,
    recording_id,
    recording_name,
    rrd_files,
    viewer_reachable,
    write_recording,
)
from cnep.pipeline.train.checkpoint import load_trained
from cnep.recordings import Trajectory, add_events, read_trajectory

log = logging.getLogger(__name__)


@writing_as("replay")
def replay(
    checkpoint_dir: str | os.PathLike,
    recording_paths: list[str | os.PathLike],
    out_rrd: str | os.PathLike,
    *,
    policy: ConditioningPolicy | None = None,
    connect: str | None = DEFAULT_VIEWER_URL,
    events_dir: str | os.PathLike | None = None,
    prediction_points: int = DEFAULT_PREDICTION_POINTS,
    merge: bool = False,
    force: bool = False,
    quiet: bool = False,
    expert_labels: Mapping[int, str] | None = None,
    marks: Mapping[Path, Sequence[tuple[int, str]]] | None = None,
) -> list[Path]:
    """Replay trajectory files through the checkpoint's CNEP; returns the .rrd files written (`rrd_files`).

    One recording goes to `out_rrd`; several go to one file each beside it (`merge`: all into `out_rrd`,
    where the viewer opens one of them, which one is not fixed).
    `policy`: the conditioning (None: the checkpoint's own, from its training).
    `connect`: a viewer URL, streamed to only if reachable (None: file only). `expert_labels`: what experts stand
    for (expert -> a behaviour's name), shown beside their numbers (None: the checkpoint's, the task of most of each
    expert's training demonstrations where they named tasks); `marks`: per recording
    path, (step, what happens there) lines for the view's switch log (a scene change). The decisions are
    written to `decisions_path(out_rrd)` (see `read_decisions`). Existing outputs (the .rrd, the
    decisions, the event copies) are refused unless `force`; a recording whose features come from
    another extractor than the checkpoint's training data is refused (pipeline.identity).
    """
    checkpoint, out = Path(checkpoint_dir), Path(out_rrd)
    paths = _checked_recordings(recording_paths, out, events_dir)
    events = Path(events_dir) if events_dir is not None else None
    files = rrd_files(out, paths, merge)
    parts = [files[0].with_name(f"{files[0].name}-{i}") for i in range(len(paths))] if len(files) < len(paths) else []
    outputs = [*files, decisions_path(out), *([events / p.name for p in paths] if events else [])]
    refuse_inputs(outputs, [*paths, checkpoint], "--out or --events-out")
    refuse_existing(outputs, force, "replay output")
    inputs = _load(checkpoint, paths)
    policy = inputs.conditioning if policy is None else policy
    live = _live_viewer(connect, files[0])
    with contextlib.ExitStack() as held:  # a failure removes the folders made for the outputs, and what was staged
        staging = _hold_outputs(held, out, events, [*files, decisions_path(out), *parts], outputs, force)
        shown = (inputs.expert_labels if expert_labels is None else expert_labels, marks or {})
        summaries = _replay_each(
            inputs,
            staging,
            files,
            parts,
            events,
            policy,
            prediction_points,
            live,
            shown,
            quiet,
            f"replay into {out.name}",
        )
        staging.write(decisions_path(out), _decisions_record(checkpoint, files, inputs.model, policy, summaries))
    for summary in summaries:
        log.debug("%s: %s", summary["recording"], _summary_line(summary))
    return files


def _decisions_record(
    checkpoint: Path, files: list[Path], model: CNEP, policy: ConditioningPolicy, summaries: list[dict]
) -> bytes:
    """The decisions file's JSON (`read_decisions`): the checkpoint, the .rrd files, the policy, each recording."""
    record = {
        "checkpoint": str(checkpoint),
        "rrd": [file.name for file in files],
        "n_experts": model.n_experts,
        "policy": policy.to_dict(),
        "recordings": summaries,
    }
    return json.dumps(record, indent=1).encode()


def _summary_line(summary: dict) -> str:
    """A recording's summary in words: its majority expert's share of the steps and its switches."""
    return (
        f"expert {summary['majority_expert']} on {100 * max(summary['share']):.0f}% of {summary['n_steps']} steps, "
        f"{len(summary['switches'])} switch(es)"
    )


def _checked_recordings(
    recording_paths: list[str | os.PathLike], out: Path, events_dir: str | os.PathLike | None
) -> list[Path]:
    """The recordings as paths, refused before anything is read: none, a missing one, an output that is not a .rrd,
    or two named alike whose copies with events would overwrite each other."""
    paths = [Path(p) for p in recording_paths]
    if not paths:
        raise PipelineError("replay needs at least one trajectory file")
    existing_files(paths, TRAJECTORIES)
    if out.suffix != ".rrd":
        raise PipelineError(f"{out}: the replay output must be a .rrd file")
    names = [p.name for p in paths]
    if events_dir is not None and len(set(names)) < len(names):
        raise PipelineError(
            f"{events_dir}: several recordings are named alike ({', '.join(sorted(names))}) and their "
            f"copies with events would overwrite each other; replay them in separate runs"
        )
    return paths


@dataclass(frozen=True)
class _Inputs:
    """The checkpoint's model and the recordings it replays: paths, trajectories, the model's rows of each (T, width),
    the predicted columns that are the end-effector's xyz, what the checkpoint says its experts stand for and the
    conditioning it was trained for."""

    model: CNEP
    paths: list[Path]
    trajectories: list[Trajectory]
    rows: list[np.ndarray]
    xyz: list[int] | None
    expert_labels: dict[int, str]
    conditioning: ConditioningPolicy


def _load(checkpoint: Path, paths: list[Path]) -> _Inputs:
    """The checkpoint and the recordings, every recording checked against it (its columns, its extractor, at least
    two steps) before anything is written."""
    trained = load_trained(checkpoint)
    trajectories = [read_trajectory(p) for p in paths]
    rows = [trained.rows(traj, p) for traj, p in zip(trajectories, paths)]  # refuse misfits first
    trained.check_extractor({p: traj.extractor for p, traj in zip(paths, trajectories)})
    for traj, p in zip(trajectories, paths):
        if traj.n_steps < 2:
            raise PipelineError(
                f"{p}: {traj.n_steps} step(s); replay needs at least 2 (time runs from the first to the last)"
            )
    xyz = trained.mapping.predicted_xyz(trained.model)
    return _Inputs(trained.model, paths, trajectories, rows, xyz, trained.expert_labels, trained.conditioning)


def _live_viewer(connect: str | None, first: Path) -> str | None:
    """`connect` when a viewer answers there, else None (with a warning naming the file to open)."""
    live = connect if connect and viewer_reachable(connect) else None
    if connect and live is None:
        log.warning(
            "no Rerun viewer answers at %s; writing %s only (open it with `cnep view %s`)",
            connect,
            first,
            shlex.quote(str(first)),
        )
    elif live:
        log.info("streaming live to %s", live)
    return live


def _hold_outputs(
    held: contextlib.ExitStack, out: Path, events: Path | None, names: list[Path], outputs: list[Path], force: bool
) -> Staging:
    """Into `held`: the output folders (removed again on failure), the locks on `names` (and on the events folder),
    one torch thread, and the staging area every output is written to; the outputs are refused again first (a run
    may have ended meanwhile)."""
    for folder, option in [(out.parent, "--out"), *([(events, "--events-out")] if events else [])]:
        held.enter_context(output_folder(folder, option))
        check_writable_folder(folder)
    held.enter_context(output_lock(out, names=[p.name for p in names]))
    if events is not None:
        held.enter_context(output_lock(events, folder=True))
    refuse_existing(outputs, force, "replay output")
    held.enter_context(torch_threads())  # one small step at a time: one thread is fastest
    return held.enter_context(staged(record=True))


def _replay_each(
    inputs: _Inputs,
    staging: Staging,
    files: list[Path],
    parts: list[Path],
    events: Path | None,
    policy: ConditioningPolicy,
    prediction_points: int,
    live: str | None,
    shown: tuple[Mapping[int, str] | None, Mapping[Path, Sequence[tuple[int, str]]]],
    quiet: bool,
    desc: str,
) -> list[dict]:
    """Step every recording through the model and stage its Rerun file (or its part of the merged one: `parts`) and
    its copy with events; returns each recording's summary (decisions.summarise), with the .rrd it went to. shown:
    the experts' labels and each recording's marks (`replay`)."""
    from cnep.pipeline.progress import progress_bar

    run_id = uuid.uuid4().hex[:8]  # a new replay is a new recording in a viewer, not more rows in an old one
    summaries = []
    expert_labels, marks = shown
    total = sum(len(r) for r in inputs.rows)
    bar = progress_bar(total=total, quiet=quiet, desc=desc, unit="step")
    for i, (path, traj, x) in enumerate(zip(inputs.paths, inputs.trajectories, inputs.rows)):
        decisions = decide(inputs.model, x, traj.timestamps_ns, policy, inputs.xyz, prediction_points)
        bar.update(len(x))
        data = write_recording(
            recording_id(i, traj, run_id),
            recording_name(i, path),
            traj,
            decisions,
            live,
            expert_labels,
            marks.get(path, ()),
        )
        if parts:  # one file holding every recording: the parts are merged into it, then dropped
            parts[i] = staging.write(parts[i], data, keep=False)
        else:
            staging.write(files[i], data)
        if events is not None:
            with output_file(events / path.name) as copy:
                add_events(path, copy, decision_events(traj, decisions))
        summaries.append(summarise(path, traj, decisions))
    bar.close()
    if parts:
        merge_rrd(parts, staging.path(files[0]), files[0])
    for i, summary in enumerate(summaries):
        summary["rrd"] = files[min(i, len(files) - 1)].name
    return summaries
