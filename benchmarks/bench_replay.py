"""Replay speed: a 1,000-step 1288-d recording with camera frames through a CNEP into an .rrd.

Run on demand (do not run it next to other heavy work):
    python -m benchmarks.bench_replay [--steps 1000] [--experts 4] [--repeats 3] [--core 0]

Writes a synthetic trajectory file (1288-d rows, 320x240 JPEG frames) and a checkpoint of an untrained
CNEP with the pipeline's widths (128-128; observes all 1288 columns, predicts pose + gripper), then
times, best of `repeats`, pinned to one core with one torch thread:
    - `replay()` end to end (read the file, online conditioning at every step, write the .rrd),
    - its parts: `read_trajectory`, `decide` (online conditioning + predicted path at every step),
      `write_recording` (Rerun, bulk `send_columns`),
    - baseline for the Rerun part: the same entities logged row by row with `rec.log`.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import timeit
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch

import cnep.pipeline.replay.viewer as L
from cnep.models import CNEPConfig, ColumnRoles, ConditioningPolicy, build_model, save_checkpoint
from cnep.outputs import write_atomically
from cnep.pipeline.replay.conditioning import decide
from cnep.pipeline.replay.rerun_log import switch_text, write_recording
from cnep.pipeline.replay.stage import replay
from cnep.pipeline.train.checkpoint import load_trained
from cnep.recordings import Episode, Trajectory, read_trajectory, write_trajectory
from cnep.recordings.constants import STEP_DIM


def best_seconds(fn: Callable[[], object], repeats: int) -> float:
    """The fastest of `repeats` timed calls after one warm-up call, in seconds."""
    fn()
    return min(timeit.repeat(fn, number=1, repeat=repeats))


def make_trajectory(steps: int, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    data = np.abs(rng.standard_normal((steps, STEP_DIM), dtype=np.float32))
    data[:, 1280:1283] = np.cumsum(rng.normal(scale=1e-2, size=(steps, 3)), axis=0)
    data[:, 1283:1287] = [0, 0, 0, 1]
    gradient = np.linspace(0, 255, 320, dtype=np.float32)[None, :, None]
    frames = []
    for k in range(steps):  # a moving gradient with sensor noise: ~realistic JPEG sizes
        img = np.clip(np.roll(gradient, k, axis=1) + rng.normal(0, 8, (240, 320, 3)), 0, 255).astype(np.uint8)
        frames.append(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
    return Trajectory(
        episode=Episode("bench", fps=30.0),
        timestamps_ns=np.arange(steps, dtype=np.int64) * 33_333_333,
        data=data,
        frames=frames,
        extractor={"architecture": "mobilenet_v2", "weights": "benchmark"},
    )


def write_per_row(path: Path, traj: Trajectory, decisions) -> None:
    """Baseline: the same entities as `write_recording`, logged one row at a time."""
    import rerun as rr

    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id="per-row")
    rec.set_sinks(rr.FileSink(path))
    d = decisions.gates.shape[1]
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(d), colors=L.expert_colors(d)), static=True)
    switches = {s.step: s for s in decisions.switches}
    for k in range(traj.n_steps):
        rec.set_time(L.TIMELINE_FRAME, sequence=k)
        rec.set_time(L.TIMELINE_TIME, timestamp=np.datetime64(int(traj.timestamps_ns[k]), "ns"))
        rec.log(L.CAMERA, rr.EncodedImage(contents=traj.frames[k], media_type="image/jpeg"))
        rec.log(L.EE, rr.Transform3D(translation=traj.pose[k, :3], quaternion=traj.pose[k, 3:]))
        rec.log(L.GATES, rr.Scalars(decisions.gates[k]))
        rec.log(L.PREDICTION, rr.LineStrips3D([decisions.predictions[k]]))
        if k in switches or k == 0:
            rec.log(L.ACTIVE_EXPERT, rr.StateChange(state=L.expert_name(int(decisions.experts[k]))))
        if k in switches:
            rec.log(L.SWITCH_LOG, rr.TextLog(switch_text(switches[k], int(traj.timestamps_ns[0]))))
    rec.flush()
    rec.disconnect()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--experts", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--core", type=int, default=0, help="CPU core to pin the process to")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    torch.set_num_threads(1)
    os.environ.setdefault("CI", "1")  # no rerun analytics
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        traj = make_trajectory(args.steps)
        rec_path = write_trajectory(tmp / "bench.mcap", traj)
        columns = ColumnRoles(width=STEP_DIM, observed=((0, STEP_DIM),), predicted=((1280, STEP_DIM),))
        model = build_model(CNEPConfig(columns=columns, n_experts=args.experts), [traj.data], seed=0)
        with torch.no_grad():
            model.gate.weight.normal_(0, 0.1)
        ckpt = save_checkpoint(model, tmp / "ckpt")
        trained = load_trained(ckpt)
        model = trained.model
        rows, xyz = trained.rows(traj, rec_path), trained.mapping.predicted_xyz(model)
        decisions = decide(model, rows, traj.timestamps_ns, ConditioningPolicy(), xyz)

        total = best_seconds(
            lambda: replay(ckpt, [rec_path], tmp / "out.rrd", connect=None, force=True, quiet=True), args.repeats
        )
        read = best_seconds(lambda: read_trajectory(rec_path), args.repeats)
        cond = best_seconds(lambda: decide(model, rows, traj.timestamps_ns, ConditioningPolicy(), xyz), args.repeats)
        bulk = best_seconds(  # the bytes written to a file, as the baseline's file sink does
            lambda: write_atomically(tmp / "bulk.rrd", write_recording("bulk", "bulk", traj, decisions, None)),
            args.repeats,
        )
        per_row = best_seconds(lambda: write_per_row(tmp / "rows.rrd", traj, decisions), args.repeats)
        mb = (tmp / "out.rrd").stat().st_size / 1e6
        frames_mb = sum(len(f) for f in traj.frames) / 1e6
    print(
        f"replay of {args.steps} steps (1288-d, {frames_mb:.1f} MB of JPEG frames), {args.experts} experts, "
        f"best of {args.repeats}, 1 thread, core {args.core}, load average {os.getloadavg()[0]:.2f}"
    )
    print("| part | seconds | steps/s |")
    print("|---|---|---|")
    for name, s in (
        ("replay() end to end", total),
        ("read_trajectory", read),
        ("decide (online conditioning)", cond),
        ("write_recording (send_columns)", bulk),
        ("baseline: per-row rec.log", per_row),
    ):
        print(f"| {name} | {s:.3f} | {args.steps / s:,.0f} |")
    print(f".rrd size {mb:.1f} MB; send_columns vs per-row log: {per_row / bulk:.1f}x faster")


if __name__ == "__main__":
    main()
