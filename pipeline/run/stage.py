"""Stage `run`: a dry run of the robot loop, a policy stepped through demonstration recordings into Rerun.

    run(RunConfig(policy=Path("policy"), recordings=(Path("demo_000.mcap"),), out=Path("run.rrd")))

The policy is an exported folder (`cnep export`, run by cnep.runtime: no torch is imported) or a checkpoint
folder (torch). Each recording's camera frames (decoded from the stored JPEG, not precomputed features),
pose and gripper are handed to `Policy.step` one step at a time, with the step's seconds since the
recording began, at the recording's rate (`realtime`) or as fast as possible. Every step goes to Rerun as
it happens: the frame, the recorded pose and path, the predicted waypoints in the active expert's colour,
the gate, the active expert, the switches and the time the step took (only `Policy.step` is timed:
decoding the JPEG and logging are not part of the robot's step). The sinks: a live viewer (`connect`),
or a .rrd file (`out`; several recordings go to one file each beside it, as `cnep replay` writes them),
written with the summary when the run completes, under the lock on `out` (cnep.outputs); `force`
replaces only .rrd files and run summaries.

The summary (`summarise`): steps, p50 / p99 / max step time, steps over the recording's frame period,
switches, per recording and in total; written beside `out` as `<out stem>.summary.json` with the conditioning the
policy ran with and the settings of it that were given (`conditioning`: they replace the policy's own).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import cnep.pipeline.replay.viewer as L
from cnep.outputs import output_lock, staged, writing_as
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import find_demonstration_files
from cnep.pipeline.progress import heartbeat
from cnep.pipeline.replay.rerun_log import (
    FLUSH_TIMEOUT_S,
    active_expert_states,
    first_read_text,
    recording_name,
    rrd_files,
    shown_state,
    viewer_reachable,
)
from cnep.pipeline.run.config import EXPORTED, RunConfig, own_conditioning, policy_kind
from cnep.recordings import Demonstration, read_demonstration
from cnep.recordings.constants import CAMERA_NAME, TOPIC_IMAGE
from cnep.runtime import STATE_KEY, TIMESTAMP_KEY, ConditioningPolicy, Policy, PolicyStep, TimeBase, load_policy
from cnep.runtime.constants import DEFAULT_PRECISION, IMAGE_KEY_PREFIX
from cnep.runtime.frames import decode_frame

log = logging.getLogger(__name__)

SUMMARY_SUFFIX = ".summary.json"


@dataclass(frozen=True)
class RecordingRun:
    """One recording stepped through the policy: step times (s), its frame period (s) and the switches."""

    path: Path
    step_s: np.ndarray
    period_s: float
    switches: int


def summary_path(out_rrd: str | os.PathLike) -> Path:
    """Where `run` writes the summary of `out_rrd`: `<stem>.summary.json` beside it."""
    out = Path(out_rrd)
    return out.with_name(out.stem + SUMMARY_SUFFIX)


def open_policy(
    path: Path,
    *,
    extractor: Path | None = None,
    precision: str = RunConfig.precision,
    backend: str = RunConfig.backend,
    threads: int | None = RunConfig.threads,
    waypoints: int = RunConfig.waypoints,
    time_base: TimeBase | None = None,
    conditioning: ConditioningPolicy | None = None,
) -> Policy:
    """The policy in folder `path`: an exported one on cnep.runtime, a checkpoint on torch (imported only then);
    conditioning: instead of the policy's own."""
    path = Path(path)
    if policy_kind(path) == EXPORTED:
        if extractor is not None:
            raise PipelineError(f"{path}: an exported policy carries its feature graph; leave out --extractor")
        return load_policy(
            path, precision=precision, backend=backend, threads=threads, waypoints=waypoints, time_base=time_base,
            conditioning=conditioning,
        )  # fmt: skip
    from cnep.pipeline.export.policy import checkpoint_policy  # a checkpoint runs on torch: import it now, not before

    if precision != DEFAULT_PRECISION:
        raise PipelineError(f"{path}: a checkpoint runs fp32 features; export it with --int8 for int8 features")
    return checkpoint_policy(
        path, extractor, threads=threads, waypoints=waypoints, time_base=time_base, conditioning=conditioning
    )


@writing_as("run")
def run(config: RunConfig) -> list[RecordingRun]:
    """Step every recording through the policy into Rerun; returns each recording's step times and switches."""
    paths = find_demonstration_files(config.recordings)
    files = rrd_files(Path(config.out), paths, merge=False) if config.out is not None else []
    outputs = [*files, summary_path(config.out)] if config.out is not None else []
    refuse_inputs(outputs, [*paths, Path(config.policy), *([Path(config.extractor)] if config.extractor else [])])
    refuse_existing(outputs, config.force, "run output")
    if config.connect is not None and not viewer_reachable(config.connect):
        raise PipelineError(
            f"{config.connect}: no Rerun viewer answers there; start one with `rerun`, or write a file with --out "
            f"and open it with `cnep view FILE` (also where there is no display)"
        )
    with heartbeat(f"reading {len(paths)} recording(s) and loading the policy", config.quiet):
        demos = [read_demonstration(p) for p in paths]
        given = config.conditioning.given()
        policy = open_policy(
            Path(config.policy),
            extractor=config.extractor,
            precision=config.precision,
            backend=config.backend,
            threads=config.threads,
            waypoints=config.waypoints,
            time_base=config.time_base,
            conditioning=config.conditioning.applied(own_conditioning(config.policy)) if given else None,
        )
    for path, demo in zip(paths, demos):
        if policy.uses_camera and demo.frames is None:
            raise PipelineError(f"{path}: has no {TOPIC_IMAGE} frames, but the policy sees the camera")
    warn_other_tasks(policy, paths, demos)
    run_id = uuid.uuid4().hex[:8]
    runs = []
    with contextlib.ExitStack() as stack:  # a failure removes the folders made for the outputs, and what was staged
        if config.out is not None:
            out = Path(config.out)
            stack.enter_context(output_folder(out.parent))
            check_writable_folder(out.parent)
            stack.enter_context(output_lock(out, names=[p.name for p in outputs]))
            refuse_existing(outputs, config.force, "run output")  # again: a run may have ended
        staging = stack.enter_context(
            staged(record=True)
        )  # the .rrd files and the summary are renamed into place together
        if policy_kind(config.policy) != EXPORTED:
            from cnep.models.threads import torch_threads

            stack.enter_context(torch_threads())  # the small model is fastest on one thread
        for i, (path, demo) in enumerate(zip(paths, demos)):
            rec, stream = recording_stream(f"{i:05d}-{demo.episode.episode_id}-{run_id}", config.connect)
            try:
                rec.send_recording_name(recording_name(i, path))
                rec.send_blueprint(L.blueprint(policy.n_experts, camera=policy.uses_camera, timing=True))
                runs.append(run_recording(policy, demo, path, rec, config.realtime))
                rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
            finally:
                rec.disconnect()
                data = stream.read(flush=True) if stream is not None else None  # drained on failure too: Rerun
                # warns on stderr about a stream dropped with bytes in it
            if data is not None:
                staging.write(files[i], data or b"")
            log.info("%s: %d steps, %d switch(es)", path, demo.n_steps, runs[-1].switches)
        if config.out is not None:
            summary = {**summarise(runs), "conditioning": policy.conditioning.to_dict(), "conditioning_given": given}
            staging.write(summary_path(config.out), json.dumps(summary, indent=1).encode())
    return runs


def warn_other_tasks(policy: Policy, paths: list[Path], demos: list[Demonstration]) -> None:
    """One warning line when recordings name a task that the policy was not trained on (where both name tasks)."""
    trained = policy.spec.tasks
    other = {demo.episode.task: path for path, demo in zip(paths, demos) if demo.episode.task not in (*trained, "")}
    if trained and other:
        given = ", ".join(f"{task!r} ({path})" for task, path in other.items())
        log.warning(
            "the recordings' task %s is not one the policy was trained on (%s); it may not do it",
            given,
            ", ".join(map(repr, trained)),
        )


def recording_stream(recording_id: str, connect: str | None):
    """A Rerun recording stream, and the binary stream of its .rrd bytes (None when it streams to the viewer at
    `connect` instead). The bytes are written by the caller, so that a full disk is an error naming the file."""
    import rerun as rr

    rec = rr.RecordingStream(L.APPLICATION_ID, recording_id=recording_id)
    if connect is not None:
        rec.set_sinks(rr.GrpcSink(connect))
        return rec, None
    stream = rec.binary_stream()
    rec.set_sinks(stream)
    return rec, stream


def run_recording(policy: Policy, demo: Demonstration, path: Path, rec, realtime: bool) -> RecordingRun:
    """Step `demo` through `policy` from a new episode, logging each step to `rec`; returns its step times."""
    ts = demo.timestamps_ns
    period_s = float(np.median(np.diff(ts))) / 1e9 if len(ts) > 1 else 0.0
    log_recording(rec, demo, policy, period_s)
    step_s = np.empty(demo.n_steps)
    switches = 0
    policy.reset()
    start, shown, labels = time.perf_counter(), None, expert_labels(policy)
    key = camera_key(policy) if policy.uses_camera else None
    for k, observation in enumerate(observations(demo, path, camera=policy.uses_camera, key=key)):
        if realtime:
            wait_until(start + observation[TIMESTAMP_KEY])
        before = time.perf_counter()
        result = policy.step(observation)
        step_s[k] = time.perf_counter() - before
        switches += result.switch is not None
        shown = log_step(rec, demo, k, result, step_s[k], period_s, shown, labels)
    return RecordingRun(path, step_s, period_s, switches)


def wait_until(deadline_s: float) -> None:
    """Sleep until `time.perf_counter()` reaches `deadline_s` (at once if it has)."""
    time.sleep(max(0.0, deadline_s - time.perf_counter()))


def camera_key(policy: Policy) -> str:
    """The observation key a recording's frames go under for `policy`: the training recordings' camera where its spec
    names one, else observation.images.rgb."""
    return policy.spec.image_key or IMAGE_KEY_PREFIX + CAMERA_NAME


def observations(demo: Demonstration, path: Path, camera: bool = True, key: str | None = None) -> Iterator[dict]:
    """The recording (read from `path`) step by step as a robot hands it to a policy: the state (8,), the seconds
    since its first step and, with `camera`, the frame decoded to (H, W, 3) uint8 RGB (one frame at a time) under
    `key` (None: observation.images.rgb)."""
    ts = demo.timestamps_ns
    state = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1).astype(np.float32)  # (T, 8)
    for k in range(demo.n_steps):
        observation = {STATE_KEY: state[k], TIMESTAMP_KEY: float(ts[k] - ts[0]) / 1e9}
        if camera:
            frame = decode_frame(demo.frames[k])
            if frame is None:
                raise PipelineError(f"{path}: step {k} on {TOPIC_IMAGE}: the frame does not decode; re-ingest it")
            observation[key or IMAGE_KEY_PREFIX + CAMERA_NAME] = frame
        yield observation


def log_recording(rec, demo: Demonstration, policy: Policy, period_s: float) -> None:
    """What holds for the whole recording: the recorded path, the series' names and colours, the frame period."""
    import rerun as rr

    d = policy.n_experts
    rec.log(L.EE, rr.TransformAxes3D(axis_length=0.05), static=True)
    rec.log(L.EE_PATH, rr.LineStrips3D([demo.pose[:, :3]], colors=[L.PATH_COLOR]), static=True)
    labels = expert_labels(policy)
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(d, labels), colors=L.expert_colors(d)), static=True)
    rec.log(L.ACTIVE_EXPERT, active_expert_states(d, labels), static=True)
    rec.log(L.STEP_TIME, rr.SeriesLines(names=["step"]), static=True)
    rec.log(L.FRAME_PERIOD, rr.SeriesLines(names=["frame period"], colors=[L.PATH_COLOR]), static=True)


def expert_labels(policy: Policy) -> dict[int, str]:
    """Expert -> what it stands for, as the policy's spec says (the task of most of its training demonstrations)."""
    return {expert: label for expert, label in enumerate(policy.spec.expert_labels) if label}


def log_step(
    rec,
    demo: Demonstration,
    k: int,
    result: PolicyStep,
    step_s: float,
    period_s: float,
    shown: str | None,
    labels: dict[int, str] | None = None,
) -> str:
    """Step k: the frame, the recorded pose, the predicted waypoints, the gate, the active expert (`unsure` where
    the gate is: `shown_state`; logged when it changes from `shown`, the previous step's), the first read or a
    switch, its time beside the frame period; experts named with `labels`. Returns the active-expert state shown at
    this step."""
    import rerun as rr

    rec.set_time(L.TIMELINE_FRAME, sequence=k)
    rec.set_time(L.TIMELINE_TIME, duration=np.timedelta64(int(demo.timestamps_ns[k] - demo.timestamps_ns[0]), "ns"))
    if demo.frames is not None:
        rec.log(L.CAMERA, rr.EncodedImage(contents=demo.frames[k], media_type="image/jpeg"))
    pose = demo.pose[k]
    rec.log(L.EE, rr.Transform3D(translation=pose[:3], quaternion=pose[3:]))
    state, color = shown_state(result.gate, result.expert, labels)
    rec.log(L.PREDICTION, rr.LineStrips3D([np.vstack([pose[:3], result.waypoints[:, :3]])], colors=[color]))
    rec.log(L.GATES, rr.Scalars(result.gate))
    if state != shown:
        rec.log(L.ACTIVE_EXPERT, rr.StateChange(state=state))
    if k == 0:
        rec.log(L.SWITCH_LOG, rr.TextLog(first_read_text(result.gate, state != L.UNSURE, labels), level="INFO"))
    if result.switch is not None:
        s = result.switch
        gate = ", ".join(f"{p:.2f}" for p in s.gate)
        names = L.expert_name(s.from_expert, labels), L.expert_name(s.to_expert, labels)
        text = f"step {k} ({result.time_s:.2f} s): {names[0]} -> {names[1]}"
        rec.log(L.SWITCH_LOG, rr.TextLog(f"{text} (p = {gate})", level="INFO"))
    rec.log(L.STEP_TIME, rr.Scalars(step_s * 1e3))
    rec.log(L.FRAME_PERIOD, rr.Scalars(period_s * 1e3))
    return state


def summarise(runs: list[RecordingRun]) -> dict:
    """Per recording and in total: steps, p50_ms, p99_ms, max_ms, over_budget (steps longer than the recording's
    frame period), switches."""

    def stats(step_s: np.ndarray, over: int, switches: int) -> dict:
        ms = step_s * 1e3
        return {
            "steps": len(ms),
            "p50_ms": round(float(np.percentile(ms, 50)), 4),
            "p99_ms": round(float(np.percentile(ms, 99)), 4),
            "max_ms": round(float(ms.max()), 4),
            "over_budget": int(over),
            "switches": int(switches),
        }

    recordings = [
        {"recording": str(r.path), "frame_period_ms": round(r.period_s * 1e3, 4)}
        | stats(r.step_s, (r.step_s > r.period_s).sum(), r.switches)
        for r in runs
    ]
    total = stats(
        np.concatenate([r.step_s for r in runs]),
        sum(rec["over_budget"] for rec in recordings),
        sum(r.switches for r in runs),
    )
    return {"recordings": recordings, "total": total}


def format_summary(summary: dict) -> str:
    """The summary as a table: one line per recording and the total."""
    head = (
        f"{'recording':<40} {'steps':>6} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'over period':>12} {'switches':>9}"
    )
    lines = [head]
    for rec in [*summary["recordings"], {"recording": "total", **summary["total"]}]:
        name = rec["recording"] if len(rec["recording"]) <= 40 else "..." + rec["recording"][-37:]
        lines.append(
            f"{name:<40} {rec['steps']:>6} {rec['p50_ms']:>8.2f} {rec['p99_ms']:>8.2f} {rec['max_ms']:>8.2f} "
            f"{rec['over_budget']:>12} {rec['switches']:>9}"
        )
    return "\n".join(lines)
