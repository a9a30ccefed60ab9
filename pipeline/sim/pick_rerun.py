"""A closed-loop pick-and-place episode as a Rerun recording, in the obstacle task's layout (pipeline.sim.rerun_log:
the replay's entity paths, colours and blueprint): the table, the mats, the cups where they stand (moved when the
table changes), the bar on its pose over time, the gripper; the camera frame, the executed path, the predicted
waypoints, the gate, the active expert, and as log lines the first read, the change of the table, every switch and
the outcome.
"""

from __future__ import annotations

from pathlib import Path

import cnep.pipeline.replay.viewer as L
from cnep.outputs import write_atomically
from cnep.pipeline.replay.rerun_log import active_expert_states
from cnep.pipeline.sim.rerun_log import (
    APPLICATION_ID,
    GRIPPER,
    GRIPPER_CENTRE,
    GRIPPER_HALF,
    TABLE,
    at_step,
    log_policy_read,
)
from cnep.sim import scene as S
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.scoring import PickEpisode

BAR, MATS, CUPS = (f"{L.WORLD}/{name}" for name in ("bar", "mats", "cups"))


def write_pick_episode(path: Path, name: str, ep: PickEpisode, n_experts: int) -> Path:
    """Write episode `ep` (run with its frames recorded) to the .rrd `path`, listed in the viewer as `name`."""
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=name)
    stream = rec.binary_stream()
    rec.send_recording_name(name)
    rec.send_blueprint(L.blueprint(n_experts, camera=True))
    _scene(rec)
    rec.log(L.EE_PATH, rr.LineStrips3D([ep.states[:, :3]], colors=[L.PATH_COLOR]), static=True)
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(n_experts), colors=L.expert_colors(n_experts)), static=True)
    rec.log(L.ACTIVE_EXPERT, active_expert_states(n_experts), static=True)
    shown = None
    for k in range(len(ep.states)):
        at_step(rec, k)
        if k == 0 or k == ep.change_step:
            _cups(rec, ep.taken_start if k == 0 else ep.taken_end)
        if k == ep.change_step:
            rec.log(L.SWITCH_LOG, rr.TextLog(f"step {k}: the table changes", level="WARN"))
        rec.log(L.CAMERA, rr.Image(ep.frames[k]))
        rec.log(L.EE, rr.Transform3D(translation=ep.states[k, :3], quaternion=ep.states[k, 3:7]))
        rec.log(BAR, rr.Transform3D(translation=ep.object_poses[k, :3], quaternion=ep.object_poses[k, 3:]))
        if k < len(ep.gates):
            shown = log_policy_read(rec, k, ep.gates, ep.experts, ep.predicted, shown)
    rec.log(L.SWITCH_LOG, rr.TextLog(_outcome(ep), level="INFO" if ep.success else "WARN"))
    rec.flush()
    rec.disconnect()
    return write_atomically(path, stream.read(flush=True) or b"")


def _outcome(ep: PickEpisode) -> str:
    if ep.success:
        return f"outcome: success, the bar on {ep.place}"
    what = "a cup touched" if ep.collision else "dropped" if ep.dropped else "never lifted" if not ep.lifted else ""
    where = f"the bar on {ep.place}" if ep.place else "the bar on no mat"
    return f"outcome: failure, {', '.join(filter(None, (what, where)))} (valid: {', '.join(ep.valid) or 'none'})"


def _scene(rec) -> None:
    """The static bodies: table, mats, the bar's and the gripper's shapes."""
    import rerun as rr

    def rgb(rgba):
        return tuple(round(255 * c) for c in rgba[:3])

    rec.log(L.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    table = rr.Boxes3D(centers=[(0, 0, -S.TABLE_HALF[2])], half_sizes=[S.TABLE_HALF], colors=[rgb(S.TABLE_RGBA)])
    rec.log(TABLE, table, static=True)
    centres = [(*xy, 0.001) for _, xy, _ in P.PLACES]
    halves = [(*P.mat_half(i), 0.001) for i in range(len(P.PLACES))]
    labels = [name for name, _, _ in P.PLACES]
    rec.log(MATS, rr.Boxes3D(centers=centres, half_sizes=halves, labels=labels, colors=[rgb(P.MAT_RGBA)]), static=True)
    bar = rr.Boxes3D(half_sizes=[P.OBJECT_HALF], colors=[rgb(P.OBJECT_RGBA)], fill_mode="solid")
    rec.log(BAR, bar, static=True)
    grip = rr.Boxes3D(centers=[GRIPPER_CENTRE], half_sizes=[GRIPPER_HALF], colors=[rgb(S.GRIPPER_RGBA)])
    rec.log(GRIPPER, grip, static=True)


def _cups(rec, taken: list[bool]) -> None:
    """The cups standing on the places `taken` (a bool per place), from the current time on."""
    import rerun as rr

    centres = [(*xy, P.CUP_HALF_HEIGHT) for (_, xy, _), t in zip(P.PLACES, taken) if t]
    half = (P.CUP_RADIUS, P.CUP_RADIUS, P.CUP_HALF_HEIGHT)
    color = tuple(round(255 * c) for c in P.CUP_RGBA[:3])
    rec.log(CUPS, rr.Boxes3D(centers=centres, half_sizes=[half] * len(centres), colors=[color], fill_mode="solid"))
