"""The replay stage: trajectory files through a trained CNEP, step by step, into Rerun.

    replay(checkpoint_dir, [recording.mcap, ...], "out.rrd") -> Path of the .rrd

For each recording, an `OnlineConditioner` (models.online) takes the steps in order, as a robot would
see them, and re-evaluates the gate at every step; the per-step gate probabilities, the active expert,
the switches and the active expert's predicted remaining trajectory go to Rerun next to the camera
frames (the stored JPEG bytes) and the end-effector pose (entities: pipeline.replay.layout).

- Always writes the `.rrd` (atomically: temporary name in the destination folder, then a rename). A
  live viewer gets the same stream only when one answers at `connect` (a TCP probe first; a warning
  when none does, never a hang). Several recordings become several Rerun recordings of one
  application in one file (merged with the `rerun rrd merge` that ships with rerun-sdk).
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

from models import CNEP, ConditioningPolicy, ExpertSwitch, OnlineConditioner, load_checkpoint, read_checkpoint_config
from models.checkpoint import atomic_write
import pipeline.replay.layout as L
from pipeline.errors import PipelineError
from recordings import Event, Trajectory, add_events, read_trajectory
from recordings.constants import BLOCK_POSE_XYZ, LAYOUTS

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
    def from_checkpoint(cls, checkpoint: Path, model: CNEP) -> "RowMapping":
        layout = read_checkpoint_config(checkpoint).get("layout")
        width = model.config.layout.width
        if isinstance(layout, dict) and "columns" in layout:
            mapping = cls(int(layout["recording_width"]), tuple((int(a), int(b)) for a, b in layout["columns"]),
                          {k: (int(a), int(b)) for k, (a, b) in layout.get("blocks", {}).items()})
        else:
            mapping = cls(width, ((0, width),), dict(LAYOUTS.get(width, {})))
        if sum(b - a for a, b in mapping.columns) != width:
            raise PipelineError(f"{checkpoint}: the layout's columns {mapping.columns} give "
                                f"{sum(b - a for a, b in mapping.columns)} model columns but the model takes {width}; "
                                f"the checkpoint is inconsistent, retrain it with `cnep train`")
        return mapping

    def select(self, traj: Trajectory, path: Path, checkpoint: Path) -> np.ndarray:
        """(T, recording_width) rows -> (T, model width) float32 rows; refuses another width."""
        if traj.width != self.recording_width:
            raise PipelineError(f"{path}: the recording has {traj.width} columns per step but the checkpoint "
                                f"{checkpoint} was trained on {self.recording_width}-column trajectories; replay "
                                f"trajectory files made like its training data (check widths with `cnep inspect`)")
        return np.concatenate([traj.data[:, a:b] for a, b in self.columns], axis=1).astype(np.float32)

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


def decide(model: CNEP, rows: np.ndarray, timestamps_ns: np.ndarray, policy: ConditioningPolicy,
           xyz: list[int] | None = None, prediction_points: int = DEFAULT_PREDICTION_POINTS) -> Decisions:
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
    quiet: bool = False,
) -> Path:
    """Replay trajectory files through the checkpoint's CNEP into `out_rrd`; returns its path.

    `connect`: a viewer URL, streamed to only if reachable (None: file only). The decisions are
    written to `decisions_path(out_rrd)` (see `read_decisions`).
    """
    import torch

    from pipeline.progress import progress_bar

    checkpoint, out = Path(checkpoint_dir), Path(out_rrd)
    paths = [Path(p) for p in recording_paths]
    if not paths:
        raise PipelineError("replay needs at least one trajectory file")
    if out.suffix != ".rrd":
        raise PipelineError(f"{out}: the replay output must be a .rrd file")
    names = [p.name for p in paths]
    if events_dir is not None and len(set(names)) < len(names):
        raise PipelineError(f"{events_dir}: several recordings are named alike ({', '.join(sorted(names))}) and their "
                            f"copies with events would overwrite each other; replay them in separate runs")
    model = load_checkpoint(checkpoint)
    mapping = RowMapping.from_checkpoint(checkpoint, model)
    trajectories = [read_trajectory(p) for p in paths]
    rows = [mapping.select(traj, p, checkpoint) for traj, p in zip(trajectories, paths)]  # refuse misfits first
    for traj, p in zip(trajectories, paths):
        if traj.n_steps < 2:
            raise PipelineError(f"{p}: {traj.n_steps} step(s); replay needs at least 2 (time runs from the first to the last)")
    xyz = mapping.predicted_xyz(model)
    live = connect if connect and viewer_reachable(connect) else None
    if connect and live is None:
        log.warning("no Rerun viewer answers at %s; writing %s only (open it with `rerun %s`)", connect, out, out)
    elif live:
        log.info("streaming live to %s", live)
    run_id = uuid.uuid4().hex[:8]  # a new replay is a new recording in a viewer, not more rows in an old one
    out.parent.mkdir(parents=True, exist_ok=True)
    if events_dir is not None:
        Path(events_dir).mkdir(parents=True, exist_ok=True)
    parts: list[Path] = []
    summaries = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one small step at a time: one thread is fastest
    try:
        bar = progress_bar(total=sum(len(r) for r in rows), quiet=quiet, desc="replay", unit="step", leave=False)
        for i, (path, traj, x) in enumerate(zip(paths, trajectories, rows)):
            decisions = decide(model, x, traj.timestamps_ns, policy, xyz, prediction_points)
            bar.update(len(x))
            parts.append(out.parent / f".{out.name}.{i}.tmp")
            write_recording(parts[-1], f"{traj.episode.episode_id}-{i}-{run_id}", path, traj, decisions, live)
            if events_dir is not None:
                add_events(path, Path(events_dir) / path.name, decision_events(traj, decisions))
            summaries.append(summarise(path, traj, decisions))
        bar.close()
        tmp = out.parent / f".{out.name}.tmp"
        if len(parts) == 1:
            os.replace(parts[0], tmp)
        else:
            merge_rrd(parts, tmp)
        os.replace(tmp, out)
    finally:
        torch.set_num_threads(threads)
        for part in [*parts, out.parent / f".{out.name}.tmp"]:
            part.unlink(missing_ok=True)
    record = {"checkpoint": str(checkpoint), "rrd": out.name, "n_experts": model.n_experts,
              "policy": {"window": policy.window, "anchors": policy.anchors}, "recordings": summaries}
    atomic_write(decisions_path(out), json.dumps(record, indent=1).encode())
    for s in summaries:
        log.debug("%s: expert %d on %.0f%% of %d steps, %d switch(es)", s["recording"], s["majority_expert"],
                 100 * max(s["share"]), s["n_steps"], len(s["switches"]))
    return out


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
        "switches": [{"step": s.step, "timestamp_ns": s.timestamp_ns, "from": s.from_expert, "to": s.to_expert,
                      "gate": np.round(s.gate, 6).tolist()} for s in decisions.switches],
    }


def decision_events(traj: Trajectory, decisions: Decisions) -> list[Event]:
    """One Event per span of an active expert: start time, duration to the next switch (or the end)."""
    ts = traj.timestamps_ns
    starts = [0] + [s.step for s in decisions.switches]
    ends = starts[1:] + [len(ts) - 1]
    events = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        meta = {"kind": "active_expert", "expert": str(decisions.experts[a]), "step": str(a),
                "previous": str(decisions.experts[a - 1]) if i else "",
                "gate": ",".join(f"{p:.4f}" for p in decisions.gates[a])}
        events.append(Event(int(ts[a]), meta, duration_ns=int(ts[b] - ts[a])))
    return events


def switch_text(switch: ExpertSwitch, start_ns: int) -> str:
    gate = ", ".join(f"{p:.2f}" for p in switch.gate)
    return (f"step {switch.step} ({(switch.timestamp_ns - start_ns) / 1e9:.2f} s): "
            f"{L.expert_name(switch.from_expert)} -> {L.expert_name(switch.to_expert)} (p = {gate})")


def write_recording(path: Path, recording_id: str, source: Path, traj: Trajectory, decisions: Decisions,
                    live: str | None) -> None:
    """One Rerun recording (file sink, plus the live viewer if any) of one replayed trajectory."""
    import rerun as rr

    d = decisions.gates.shape[1]
    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id=recording_id)
    rec.set_sinks(rr.FileSink(path), *([rr.GrpcSink(live)] if live else []))
    rec.send_recording_name(f"{traj.episode.episode_id} ({source.name})")
    rec.send_blueprint(L.blueprint(d))
    steps = np.arange(traj.n_steps)
    index = [rr.TimeColumn(L.TIMELINE_FRAME, sequence=steps),
             rr.TimeColumn(L.TIMELINE_TIME, timestamp=traj.timestamps_ns.astype("datetime64[ns]"))]
    log_camera(rec, index, traj)
    log_pose(rec, index, traj)
    log_gates(rec, index, decisions.gates)
    log_active_expert(rec, traj, decisions, d)
    log_switches(rec, traj, decisions)
    if decisions.predictions is not None:
        rec.send_columns(L.PREDICTION, indexes=index, columns=rr.LineStrips3D.columns(strips=list(decisions.predictions)))
    rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    rec.disconnect()


def log_camera(rec, index, traj: Trajectory) -> None:
    """The stored JPEG bytes, one image per step (nothing for motion-only recordings)."""
    import rerun as rr

    if traj.frames is None:
        return
    rec.send_columns(L.CAMERA, indexes=index,
                     columns=rr.EncodedImage.columns(blob=traj.frames, media_type=["image/jpeg"] * len(traj.frames)))


def log_pose(rec, index, traj: Trajectory) -> None:
    """End-effector pose per step (Transform3D, quaternion xyzw) and the whole path (static)."""
    import rerun as rr

    pose = traj.pose  # (T, 7)
    rec.log(L.EE, rr.TransformAxes3D(axis_length=0.05), static=True)
    rec.send_columns(L.EE, indexes=index, columns=rr.Transform3D.columns(translation=pose[:, :3], quaternion=pose[:, 3:]))
    rec.log(L.EE_PATH, rr.LineStrips3D([pose[:, :3]], colors=[L.PATH_COLOR]), static=True)


def log_gates(rec, index, gates: np.ndarray) -> None:
    """(T, d) gate probabilities: one row of d scalars per step, series named and coloured per expert."""
    import rerun as rr

    d = gates.shape[1]
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(d), colors=L.expert_colors(d)), static=True)
    rec.send_columns(L.GATES, indexes=index, columns=rr.Scalars.columns(scalars=gates))


def change_index(traj: Trajectory, steps: list[int]):
    import rerun as rr

    return [rr.TimeColumn(L.TIMELINE_FRAME, sequence=steps),
            rr.TimeColumn(L.TIMELINE_TIME, timestamp=traj.timestamps_ns[steps].astype("datetime64[ns]"))]


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
    rec.send_columns(L.SWITCH_LOG, indexes=change_index(traj, [s.step for s in decisions.switches]),
                     columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)))


def merge_rrd(parts: list[Path], dst: Path) -> None:
    """Several single-recording .rrd files -> one file holding them all (rerun's own merge)."""
    cmd = [sys.executable, "-m", "rerun_cli", "rrd", "merge", *map(str, parts), "-o", str(dst)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise PipelineError(f"{dst}: `rerun rrd merge` failed ({done.stderr.strip().splitlines()[-1:]})")
