"""The replay in Rerun: one recording stream per replayed trajectory, written to a file and, if one answers,
to a live viewer.

One `log_<source>()` function per source (camera, pose, gate, active expert, first read and switches) sends whole
columns at once (`send_columns`); where each goes is `pipeline.replay.viewer`. `merge_rrd` puts several
single-recording files into one with rerun's own merge, `rrd_files` names the files of several recordings;
`viewer_reachable` probes a viewer before streaming to it (a warning when none answers, never a hang) and
`serve` hosts a server for viewers.
"""

from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlparse

import numpy as np

import cnep.pipeline.replay.viewer as L
from cnep.pipeline.errors import PipelineError
from cnep.recordings import Trajectory
from cnep.runtime.conditioning import ExpertSwitch

if TYPE_CHECKING:  # the conditioning runs the torch model; this module (`cnep run` uses it) imports no torch
    from cnep.pipeline.replay.conditioning import Decisions

Labels = Mapping[int, str] | None  # what experts stand for, where the caller knows (expert -> name)

DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"  # where a local `rerun` viewer listens
PROBE_TIMEOUT_S = 0.5
FLUSH_TIMEOUT_S = 30.0  # a live viewer that stops reading may delay the end of a replay, never block it


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


def serve_until_interrupted() -> None:
    """Keep a `serve` server's data available to viewers until Ctrl-C (or SIGTERM, which cnep turns into it)."""
    import time

    print("serving until Ctrl-C")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass


def rrd_files(out: Path, paths: list[Path], merge: bool) -> list[Path]:
    """The .rrd files of a replay: `out` for one recording (or all of them, merged), else one per recording beside it,
    `<out stem>-NN-<folder>-<file stem>.rrd` in the order given (a file holding one recording opens on it)."""
    if merge or len(paths) == 1:
        return [out]
    return [
        out.with_name(f"{out.stem}-{i + 1:02d}-{path.parent.name}-{path.stem}.rrd".replace(" ", "_"))
        for i, path in enumerate(paths)
    ]


def switch_text(switch: ExpertSwitch, start_ns: int, labels: Labels = None) -> str:
    gate = ", ".join(f"{p:.2f}" for p in switch.gate)
    return (
        f"step {switch.step} ({(switch.timestamp_ns - start_ns) / 1e9:.2f} s): "
        f"{L.expert_name(switch.from_expert, labels)} -> {L.expert_name(switch.to_expert, labels)} (p = {gate})"
    )


def recording_id(index: int, traj: Trajectory, run_id: str) -> str:
    """The Rerun recording id of the `index`-th replayed recording: `rerun rrd merge` orders a file's recordings
    by id, so the zero-padded index keeps them in the order given."""
    return f"{index:05d}-{traj.episode.episode_id}-{run_id}"


def recording_name(index: int, source: Path) -> str:
    """The name the viewer lists (narrow: what tells recordings apart comes first): `demo_000 (scene_change) #1`."""
    return f"{source.stem} ({source.parent.name or '.'}) #{index + 1}"


def write_recording(
    recording_id: str,
    name: str,
    traj: Trajectory,
    decisions: Decisions,
    live: str | None,
    labels: Labels = None,
    marks: Sequence[tuple[int, str]] = (),
) -> bytes:
    """One Rerun recording of one replayed trajectory: its .rrd bytes (and the same stream to the live viewer, if
    any). The bytes are written by the caller, so that a full disk is an error naming the file, not Rerun's.

    labels: what experts stand for, where the caller knows (expert -> a behaviour's name), shown beside their
    numbers; marks: (step, what happens there) lines for the switch log, such as a scene change."""
    import rerun as rr

    d = decisions.gates.shape[1]
    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id=recording_id)
    stream = rec.binary_stream()
    rec.set_sinks(stream, *([rr.GrpcSink(live)] if live else []))
    rec.send_recording_name(name)
    rec.send_blueprint(L.blueprint(d, camera=traj.frames is not None))
    index = change_index(traj, list(range(traj.n_steps)))
    log_camera(rec, index, traj)
    log_pose(rec, index, traj)
    log_gates(rec, index, decisions.gates, labels)
    log_active_expert(rec, traj, decisions, d, labels)
    log_switches(rec, traj, decisions, labels, marks)
    if decisions.predictions is not None:
        colors = [c for _, c in shown_states(decisions, labels)]  # the active expert's colour, grey where unsure
        rec.send_columns(
            L.PREDICTION,
            indexes=index,
            columns=rr.LineStrips3D.columns(strips=list(decisions.predictions), colors=colors),
        )
    rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    rec.disconnect()
    return stream.read(flush=True) or b""


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


def log_gates(rec, index, gates: np.ndarray, labels: Labels = None) -> None:
    """(T, d) gate probabilities: one row of d scalars per step, series named and coloured per expert."""
    import rerun as rr

    d = gates.shape[1]
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(d, labels), colors=L.expert_colors(d)), static=True)
    rec.send_columns(L.GATES, indexes=index, columns=rr.Scalars.columns(scalars=gates))


def change_index(traj: Trajectory, steps: list[int]):
    """Rerun time columns of `steps`: the step index, and the time since the recording's first step (a duration)."""
    import rerun as rr

    since_start = (traj.timestamps_ns[steps] - traj.timestamps_ns[0]).astype("timedelta64[ns]")
    return [rr.TimeColumn(L.TIMELINE_FRAME, sequence=steps), rr.TimeColumn(L.TIMELINE_TIME, duration=since_start)]


def shown_state(gate: np.ndarray, expert: int, labels: Labels = None) -> tuple[str, tuple[int, int, int]]:
    """The state the active-expert lane shows for a step's gate (d,) and active expert, and its colour: the expert,
    or L.UNSURE where it holds less than L.SURE_GATE."""
    if gate[expert] < L.SURE_GATE:
        return L.UNSURE, L.UNSURE_COLOR
    return L.expert_name(int(expert), labels), L.expert_colors(len(gate))[expert]


def shown_states(decisions: Decisions, labels: Labels = None) -> list[tuple[str, tuple[int, int, int]]]:
    """(T,) `shown_state` at each step of a replayed recording."""
    return [shown_state(gate, int(e), labels) for gate, e in zip(decisions.gates, decisions.experts)]


def active_expert_states(d: int, labels: Labels = None):
    """The active-expert lane's StateConfiguration for `d` experts: each expert in its colour, and L.UNSURE."""
    import rerun as rr

    names = L.expert_names(d, labels)
    return rr.StateConfiguration(values=[*names, L.UNSURE], colors=[*L.expert_colors(d), L.UNSURE_COLOR])


def log_active_expert(rec, traj: Trajectory, decisions: Decisions, d: int, labels: Labels = None) -> None:
    """The active expert as a colour lane (`shown_states`): a StateChange at the first step and at each change."""
    import rerun as rr

    rec.log(L.ACTIVE_EXPERT, active_expert_states(d, labels), static=True)
    states = [state for state, _ in shown_states(decisions, labels)]
    steps = [k for k in range(len(states)) if k == 0 or states[k] != states[k - 1]]
    rec.send_columns(
        L.ACTIVE_EXPERT,
        indexes=change_index(traj, steps),
        columns=rr.StateChange.columns(state=[states[k] for k in steps]),
    )


def first_read_text(gate: np.ndarray, sure: bool, labels: Labels = None) -> str:
    """The log line of the gate's step-0 read (d,): the expert it is sure of, or that it is unsure and between which
    experts (those above a tenth, most probable first)."""
    ranked = [int(e) for e in np.argsort(-gate) if gate[e] >= 0.1] or [int(gate.argmax())]
    if sure:
        return f"step 0 (0.00 s): first read {L.expert_name(ranked[0], labels)} (p = {gate[ranked[0]]:.2f})"
    between = ", ".join(f"{L.expert_name(e, labels)} {gate[e]:.2f}" for e in ranked)
    return f"step 0 (0.00 s): first read unsure ({between})"


def log_switches(
    rec, traj: Trajectory, decisions: Decisions, labels: Labels = None, marks: Sequence[tuple[int, str]] = ()
) -> None:
    """The TextLog: the first read at step 0 (`first_read_text`), then one line per switch and per mark (a scene
    change: level WARN, so that it stands out), at its step."""
    import rerun as rr

    start = int(traj.timestamps_ns[0])
    lines = [(0, first_read_text(decisions.gates[0], not decisions.unsure()[0], labels), "INFO")]
    lines += [(s.step, switch_text(s, start, labels), "INFO") for s in decisions.switches]
    lines += [
        (step, f"step {step} ({(traj.timestamps_ns[step] - start) / 1e9:.2f} s): {what}", "WARN")
        for step, what in marks
    ]
    lines.sort(key=lambda line: line[0])  # stable: at one step the expert lines come first
    rec.send_columns(
        L.SWITCH_LOG,
        indexes=change_index(traj, [step for step, _, _ in lines]),
        columns=rr.TextLog.columns(text=[text for _, text, _ in lines], level=[level for _, _, level in lines]),
    )


def merge_rrd(parts: list[Path], dst: Path, target: Path) -> None:
    """Several single-recording .rrd files -> one file `dst` holding them all (rerun's own merge); `target` is the
    file `dst` becomes, named in errors (a full disk there is the OSError of any other write)."""
    cmd = [sys.executable, "-m", "rerun_cli", "rrd", "merge", *map(str, parts), "-o", str(dst)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        said = " ".join(done.stderr.strip().splitlines()[-1:])
        for code in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES):
            if os.strerror(code) in done.stderr:
                raise OSError(code, os.strerror(code), str(target))
        raise PipelineError(f"{target}: `rerun rrd merge` failed ({said}); run the replay again without --merge")
