"""The replay stage: trajectory files through a trained CNEP, step by step, into Rerun.

    replay(checkpoint_dir, [recording.mcap, ...], "out.rrd") -> [the .rrd files written]

For each recording, an `OnlineConditioner` (models.online) takes the steps in order, as a robot would
see them, and re-evaluates the gate at every step; the per-step gate probabilities, the active expert,
the switches and the active expert's predicted remaining trajectory go to Rerun next to the camera
frames (the stored JPEG bytes) and the end-effector pose (entities: pipeline.replay.layout).

- Always writes the `.rrd` (atomically: temporary name in the destination folder, then a rename). A
  live viewer gets the same stream only when one answers at `connect` (a TCP probe first; a warning
  when none does, never a hang). Several recordings become one file each beside `out.rrd`
  (`out-01-<folder>-<name>.rrd`, ...: a file of one recording opens on it), or with `merge` several
  Rerun recordings of one application in `out.rrd` (merged with the `rerun rrd merge` of rerun-sdk).
- The decisions (gate and expert per step, switches, each expert's share of the steps) are returned
  by `decide` and written next to the .rrd as `<name>.experts.json` (`read_decisions`).
- With `events_dir`, a copy of each recording with the decisions on `/events` (one Event per span of
  an active expert) is written there, so Foxglove shows them (the input is never modified).

Which recording columns the model sees: the checkpoint's `layout` entry (written by `cnep train`:
`recording_width`, `columns` = spans of the recording handed to the model, `blocks` = where each
block lies in model columns); without it, the model's own layout over the whole row. A recording of
another width is refused.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import subprocess
import sys
import uuid
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

import cnep.pipeline.replay.layout as L
from cnep.models import (
    CNEP,
    ConditioningPolicy,
    ExpertSwitch,
    OnlineConditioner,
    load_checkpoint,
    read_checkpoint_config,
)
from cnep.models.checkpoint import CONFIG_FILE, atomic_write
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_existing
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.identity import check_checkpoint_extractor
from cnep.recordings import Event, Trajectory, add_events, read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_POSE_XYZ, BLOCKS_BY_WIDTH

log = logging.getLogger(__name__)

DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"  # where a local `rerun` viewer listens
PROBE_TIMEOUT_S = 0.5
FLUSH_TIMEOUT_S = 30.0  # a live viewer that stops reading may delay the end of a replay, never block it
DEFAULT_PREDICTION_POINTS = 25  # points of the predicted remaining trajectory drawn per step
DECISIONS_SUFFIX = ".experts.json"


@dataclass(frozen=True)
class RowMapping:
    """Recording columns -> model columns. `blocks`: block name -> (start, stop) in model columns."""

    recording_width: int
    columns: tuple[tuple[int, int], ...]
    blocks: dict[str, tuple[int, int]]

    @classmethod
    def from_checkpoint(cls, checkpoint: Path, model: CNEP) -> RowMapping:
        layout = read_checkpoint_config(checkpoint).get("layout")
        width = model.config.columns.width
        if isinstance(layout, dict) and "columns" in layout:
            mapping = cls(
                int(layout["recording_width"]),
                tuple((int(a), int(b)) for a, b in layout["columns"]),
                {k: (int(a), int(b)) for k, (a, b) in layout.get("blocks", {}).items()},
            )
        else:
            mapping = cls(width, ((0, width),), dict(BLOCKS_BY_WIDTH.get(width, {})))
        if sum(b - a for a, b in mapping.columns) != width:
            raise PipelineError(
                f"{checkpoint}: the layout's columns {mapping.columns} give "
                f"{sum(b - a for a, b in mapping.columns)} model columns but the model takes {width}; "
                f"the checkpoint is inconsistent, retrain it with `cnep train`"
            )
        return mapping

    def select(self, traj: Trajectory, path: Path, checkpoint: Path) -> np.ndarray:
        """(T, recording width) rows -> (T, model width) float32 rows.

        A recording of the training width gives the checkpoint's columns; one of another width gives the
        model's blocks found by name in its own layout (a `motion` checkpoint takes the pose and gripper
        of 8- and 1288-column recordings alike); a recording without one of those blocks is refused.
        """
        if traj.width == self.recording_width:
            spans = self.columns
        else:
            missing = [name for name in self.blocks if name not in traj.blocks]
            if missing or not self.blocks:
                raise PipelineError(
                    f"{path}: the recording has {traj.width} columns per step "
                    f"({', '.join(traj.blocks)}) but the checkpoint {checkpoint} was trained on "
                    f"{self.recording_width}-column trajectories and needs "
                    f"{', '.join(missing or ['its training layout'])}; replay trajectory files made "
                    f"like its training data (check widths with `cnep inspect`)"
                )
            spans = tuple(traj.blocks[name] for name in sorted(self.blocks, key=lambda n: self.blocks[n][0]))
        return np.concatenate([traj.data[:, a:b] for a, b in spans], axis=1).astype(np.float32)

    @property
    def uses_features(self) -> bool:
        """True if the model sees the image features (so they must come from the checkpoint's extractor)."""
        return BLOCK_FEATURES in self.blocks

    def predicted_xyz(self, model: CNEP) -> list[int] | None:
        """Positions of the pose xyz columns among the model's predicted columns (None if not predicted)."""
        if BLOCK_POSE_XYZ not in self.blocks:
            return None
        out = model.out_columns.tolist()
        a, b = self.blocks[BLOCK_POSE_XYZ]
        return [out.index(c) for c in range(a, b)] if all(c in out for c in range(a, b)) else None


@dataclass
class Decisions:
    """What the gate decided at each step of one recording.

    gates (T, d), each row sums to 1; experts (T,) argmax per step; switches: one per argmax change;
    predictions (T, P, 3) the active expert's predicted remaining path (xyz) from each step, or None
    when the model does not predict the pose.
    """

    gates: np.ndarray
    experts: np.ndarray
    switches: list[ExpertSwitch]
    predictions: np.ndarray | None

    def share(self) -> np.ndarray:
        """(d,) fraction of the steps each expert was active."""
        return np.bincount(self.experts, minlength=self.gates.shape[1]) / len(self.experts)


def decide(
    model: CNEP,
    rows: np.ndarray,
    timestamps_ns: np.ndarray,
    policy: ConditioningPolicy,
    xyz: list[int] | None = None,
    prediction_points: int = DEFAULT_PREDICTION_POINTS,
) -> Decisions:
    """Step an online conditioner through `rows` (T, model width) at `timestamps_ns` (T,)."""
    T, d = len(rows), model.n_experts
    online = OnlineConditioner(model, horizon=T, policy=policy)
    gates, experts = np.empty((T, d)), np.empty(T, dtype=np.int64)
    predictions = np.empty((T, prediction_points, 3), dtype=np.float32) if xyz is not None else None
    switches = []
    for k in range(T):
        step = online.step(rows[k], int(timestamps_ns[k]))
        gates[k], experts[k] = step.gate, step.expert
        if step.switch is not None:
            switches.append(step.switch)
        if predictions is not None:
            mean, _ = online.predict(np.linspace(step.t, 1.0, prediction_points))  # (P, dy)
            predictions[k] = mean[:, xyz]
    return Decisions(gates, experts, switches, predictions)


def viewer_reachable(url: str) -> bool:
    """True if something accepts TCP connections at the URL's host and port."""
    parsed = urlparse(url)
    try:
        with socket.create_connection((parsed.hostname or "127.0.0.1", parsed.port or 9876), timeout=PROBE_TIMEOUT_S):
            return True
    except OSError:
        return False


def serve(port: int = 9876):
    """Host a gRPC proxy that viewers can connect to (late viewers get everything); returns (handle, url).

    Keep the handle alive as long as the data should be served; pass the url as `connect` to `replay`.
    """
    import rerun as rr

    server = rr.RecordingStream(L.APPLICATION_ID, recording_id="cnep-replay-server")
    return server, server.serve_grpc(grpc_port=port)


def replay(
    checkpoint_dir: str | os.PathLike,
    recording_paths: list[str | os.PathLike],
    out_rrd: str | os.PathLike,
    *,
    policy: ConditioningPolicy = ConditioningPolicy(),
    connect: str | None = DEFAULT_VIEWER_URL,
    events_dir: str | os.PathLike | None = None,
    prediction_points: int = DEFAULT_PREDICTION_POINTS,
    merge: bool = False,
    force: bool = False,
    quiet: bool = False,
) -> list[Path]:
    """Replay trajectory files through the checkpoint's CNEP; returns the .rrd files written (`rrd_files`).

    One recording goes to `out_rrd`; several go to one file each beside it (`merge`: all into `out_rrd`,
    where the viewer opens one of them, which one is not fixed).
    `connect`: a viewer URL, streamed to only if reachable (None: file only). The decisions are
    written to `decisions_path(out_rrd)` (see `read_decisions`). Existing outputs (the .rrd, the
    decisions, the event copies) are refused unless `force`; a recording whose features come from
    another extractor than the checkpoint's training data is refused (pipeline.identity).
    """
    import torch

    from cnep.pipeline.progress import progress_bar

    checkpoint, out = Path(checkpoint_dir), Path(out_rrd)
    paths = [Path(p) for p in recording_paths]
    if not paths:
        raise PipelineError("replay needs at least one trajectory file")
    if out.suffix != ".rrd":
        raise PipelineError(f"{out}: the replay output must be a .rrd file")
    names = [p.name for p in paths]
    if events_dir is not None and len(set(names)) < len(names):
        raise PipelineError(
            f"{events_dir}: several recordings are named alike ({', '.join(sorted(names))}) and their "
            f"copies with events would overwrite each other; replay them in separate runs"
        )
    files = rrd_files(out, paths, merge)
    outputs = [*files, decisions_path(out), *(Path(events_dir) / name for name in names if events_dir is not None)]
    refuse_existing(outputs, force, "replay output")
    model = load_checkpoint(checkpoint)
    mapping = RowMapping.from_checkpoint(checkpoint, model)
    trajectories = [read_trajectory(p) for p in paths]
    rows = [mapping.select(traj, p, checkpoint) for traj, p in zip(trajectories, paths)]  # refuse misfits first
    if mapping.uses_features:
        trained = read_checkpoint_config(checkpoint).get("extractor") or {}
        check_checkpoint_extractor(
            checkpoint / CONFIG_FILE, trained, {p: traj.extractor for p, traj in zip(paths, trajectories)}
        )
    for traj, p in zip(trajectories, paths):
        if traj.n_steps < 2:
            raise PipelineError(
                f"{p}: {traj.n_steps} step(s); replay needs at least 2 (time runs from the first to the last)"
            )
    xyz = mapping.predicted_xyz(model)
    live = connect if connect and viewer_reachable(connect) else None
    if connect and live is None:
        log.warning(
            "no Rerun viewer answers at %s; writing %s only (open it with `rerun %s`)", connect, files[0], files[0]
        )
    elif live:
        log.info("streaming live to %s", live)
    run_id = uuid.uuid4().hex[:8]  # a new replay is a new recording in a viewer, not more rows in an old one
    parts: list[Path] = []
    summaries = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one small step at a time: one thread is fastest
    with contextlib.ExitStack() as made:  # a failure removes the folders made for the outputs, and the parts
        for folder, option in [(out.parent, "--out"), *([(Path(events_dir), "--events-out")] if events_dir else [])]:
            made.enter_context(output_folder(folder, option))
            check_writable_folder(folder)
        made.callback(torch.set_num_threads, threads)
        made.callback(lambda: [part.unlink(missing_ok=True) for part in [*parts, out.parent / f".{out.name}.tmp"]])
        bar = progress_bar(total=sum(len(r) for r in rows), quiet=quiet, desc="replay", unit="step", leave=False)
        for i, (path, traj, x) in enumerate(zip(paths, trajectories, rows)):
            decisions = decide(model, x, traj.timestamps_ns, policy, xyz, prediction_points)
            bar.update(len(x))
            parts.append(out.parent / f".{out.name}.{i}.tmp")
            write_recording(parts[-1], recording_id(i, traj, run_id), recording_name(i, path), traj, decisions, live)
            if events_dir is not None:
                add_events(path, Path(events_dir) / path.name, decision_events(traj, decisions))
            summaries.append(summarise(path, traj, decisions))
        bar.close()
        done = parts
        if len(files) < len(parts):  # one file holding every recording
            done = [out.parent / f".{out.name}.tmp"]
            merge_rrd(parts, done[0])
        for i, summary in enumerate(summaries):
            summary["rrd"] = files[min(i, len(files) - 1)].name
        record = {
            "checkpoint": str(checkpoint),
            "rrd": [file.name for file in files],
            "n_experts": model.n_experts,
            "policy": {"window": policy.window, "anchors": policy.anchors},
            "recordings": summaries,
        }
        atomic_write(decisions_path(out), json.dumps(record, indent=1).encode())
        for part, file in zip(done, files):
            os.replace(part, file)
    for s in summaries:
        log.debug(
            "%s: expert %d on %.0f%% of %d steps, %d switch(es)",
            s["recording"],
            s["majority_expert"],
            100 * max(s["share"]),
            s["n_steps"],
            len(s["switches"]),
        )
    return files


def rrd_files(out: Path, paths: list[Path], merge: bool) -> list[Path]:
    """The .rrd files of a replay: `out` for one recording (or all of them, merged), else one per recording beside it,
    `<out stem>-NN-<folder>-<file stem>.rrd` in the order given (a file holding one recording opens on it)."""
    if merge or len(paths) == 1:
        return [out]
    return [
        out.with_name(f"{out.stem}-{i + 1:02d}-{path.parent.name}-{path.stem}.rrd".replace(" ", "_"))
        for i, path in enumerate(paths)
    ]


def decisions_path(out_rrd: str | os.PathLike) -> Path:
    """Where `replay` writes the decisions of `out_rrd`: `<stem>.experts.json` beside it."""
    out = Path(out_rrd)
    return out.with_name(out.stem + DECISIONS_SUFFIX)


def read_decisions(out_rrd: str | os.PathLike) -> dict:
    """The decisions `replay` wrote for `out_rrd`: per recording, `experts` (T,), `gates` (T, d), `share`
    (d,), `majority_expert`, `switches` [{step, timestamp_ns, from, to, gate}]."""
    path = decisions_path(out_rrd)
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PipelineError(f"{path}: cannot read the replay decisions ({exc}); run `cnep replay` again") from None


def summarise(path: Path, traj: Trajectory, decisions: Decisions) -> dict:
    share = decisions.share()
    return {
        "recording": str(path),
        "episode_id": traj.episode.episode_id,
        "n_steps": len(decisions.experts),
        "majority_expert": int(share.argmax()),
        "share": [round(float(s), 6) for s in share],
        "experts": decisions.experts.tolist(),
        "gates": np.round(decisions.gates, 6).tolist(),
        "switches": [
            {
                "step": s.step,
                "timestamp_ns": s.timestamp_ns,
                "from": s.from_expert,
                "to": s.to_expert,
                "gate": np.round(s.gate, 6).tolist(),
            }
            for s in decisions.switches
        ],
    }


def decision_events(traj: Trajectory, decisions: Decisions) -> list[Event]:
    """One Event per span of an active expert: start time, duration to the next switch (or the end)."""
    ts = traj.timestamps_ns
    starts = [0] + [s.step for s in decisions.switches]
    ends = starts[1:] + [len(ts) - 1]
    events = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        meta = {
            "kind": "active_expert",
            "expert": str(decisions.experts[a]),
            "step": str(a),
            "previous": str(decisions.experts[a - 1]) if i else "",
            "gate": ",".join(f"{p:.4f}" for p in decisions.gates[a]),
        }
        events.append(Event(int(ts[a]), meta, duration_ns=int(ts[b] - ts[a])))
    return events


def switch_text(switch: ExpertSwitch, start_ns: int) -> str:
    gate = ", ".join(f"{p:.2f}" for p in switch.gate)
    return (
        f"step {switch.step} ({(switch.timestamp_ns - start_ns) / 1e9:.2f} s): "
        f"{L.expert_name(switch.from_expert)} -> {L.expert_name(switch.to_expert)} (p = {gate})"
    )


def recording_id(index: int, traj: Trajectory, run_id: str) -> str:
    """The Rerun recording id of the `index`-th replayed recording: `rerun rrd merge` orders a file's recordings
    by id, so the zero-padded index keeps them in the order given."""
    return f"{index:05d}-{traj.episode.episode_id}-{run_id}"


def recording_name(index: int, source: Path) -> str:
    """The name the viewer lists (narrow: what tells recordings apart comes first): `demo_000 (scene_change) #1`."""
    return f"{source.stem} ({source.parent.name or '.'}) #{index + 1}"


def write_recording(
    path: Path, recording_id: str, name: str, traj: Trajectory, decisions: Decisions, live: str | None
) -> None:
    """One Rerun recording (file sink, plus the live viewer if any) of one replayed trajectory."""
    import rerun as rr

    d = decisions.gates.shape[1]
    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id=recording_id)
    rec.set_sinks(rr.FileSink(path), *([rr.GrpcSink(live)] if live else []))
    rec.send_recording_name(name)
    rec.send_blueprint(L.blueprint(d, camera=traj.frames is not None))
    index = change_index(traj, list(range(traj.n_steps)))
    log_camera(rec, index, traj)
    log_pose(rec, index, traj)
    log_gates(rec, index, decisions.gates)
    log_active_expert(rec, traj, decisions, d)
    log_switches(rec, traj, decisions)
    if decisions.predictions is not None:
        colors = [L.expert_colors(d)[e] for e in decisions.experts]  # the active expert's colour at each step
        rec.send_columns(
            L.PREDICTION,
            indexes=index,
            columns=rr.LineStrips3D.columns(strips=list(decisions.predictions), colors=colors),
        )
    rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    rec.disconnect()


def log_camera(rec, index, traj: Trajectory) -> None:
    """The stored JPEG bytes, one image per step (nothing for motion-only recordings)."""
    import rerun as rr

    if traj.frames is None:
        return
    rec.send_columns(
        L.CAMERA,
        indexes=index,
        columns=rr.EncodedImage.columns(blob=traj.frames, media_type=["image/jpeg"] * len(traj.frames)),
    )


def log_pose(rec, index, traj: Trajectory) -> None:
    """End-effector pose per step (Transform3D, quaternion xyzw) and the whole path (static)."""
    import rerun as rr

    pose = traj.pose  # (T, 7)
    rec.log(L.EE, rr.TransformAxes3D(axis_length=0.05), static=True)
    rec.send_columns(
        L.EE, indexes=index, columns=rr.Transform3D.columns(translation=pose[:, :3], quaternion=pose[:, 3:])
    )
    rec.log(L.EE_PATH, rr.LineStrips3D([pose[:, :3]], colors=[L.PATH_COLOR]), static=True)


def log_gates(rec, index, gates: np.ndarray) -> None:
    """(T, d) gate probabilities: one row of d scalars per step, series named and coloured per expert."""
    import rerun as rr

    d = gates.shape[1]
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(d), colors=L.expert_colors(d)), static=True)
    rec.send_columns(L.GATES, indexes=index, columns=rr.Scalars.columns(scalars=gates))


def change_index(traj: Trajectory, steps: list[int]):
    """Rerun time columns of `steps`: the step index, and the time since the recording's first step (a duration)."""
    import rerun as rr

    since_start = (traj.timestamps_ns[steps] - traj.timestamps_ns[0]).astype("timedelta64[ns]")
    return [rr.TimeColumn(L.TIMELINE_FRAME, sequence=steps), rr.TimeColumn(L.TIMELINE_TIME, duration=since_start)]


def log_active_expert(rec, traj: Trajectory, decisions: Decisions, d: int) -> None:
    """The active expert as a colour lane: a StateChange at the first step and at each switch."""
    import rerun as rr

    rec.log(L.ACTIVE_EXPERT, rr.StateConfiguration(values=L.expert_names(d), colors=L.expert_colors(d)), static=True)
    steps = [0] + [s.step for s in decisions.switches]
    states = [L.expert_name(int(decisions.experts[k])) for k in steps]
    rec.send_columns(L.ACTIVE_EXPERT, indexes=change_index(traj, steps), columns=rr.StateChange.columns(state=states))


def log_switches(rec, traj: Trajectory, decisions: Decisions) -> None:
    """One TextLog line per switch, at the step of the switch."""
    import rerun as rr

    if not decisions.switches:
        return
    start = int(traj.timestamps_ns[0])
    texts = [switch_text(s, start) for s in decisions.switches]
    rec.send_columns(
        L.SWITCH_LOG,
        indexes=change_index(traj, [s.step for s in decisions.switches]),
        columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)),
    )


def merge_rrd(parts: list[Path], dst: Path) -> None:
    """Several single-recording .rrd files -> one file holding them all (rerun's own merge)."""
    cmd = [sys.executable, "-m", "rerun_cli", "rrd", "merge", *map(str, parts), "-o", str(dst)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise PipelineError(f"{dst}: `rerun rrd merge` failed ({done.stderr.strip().splitlines()[-1:]})")
