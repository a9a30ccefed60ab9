"""A closed-loop episode as a Rerun recording, in the replay's layout (pipeline.replay.viewer: its entity paths,
colours and blueprint) with the task's scene added as its drawing describes it (sim.drawing: the table and the task's
shapes, its object on its poses over time, the shapes that change during the episode, the gripper as a box on the end
effector's pose); the camera frame, the executed path, the predicted waypoints in the active expert's colour (grey
where the gate is unsure), the gate, the active expert, and as log lines the first read, every switch, the drawing's
notes (a contact marked on the gripper) and the outcome.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import cnep.pipeline.replay.viewer as L
from cnep.outputs import write_output
from cnep.pipeline.replay.rerun_log import active_expert_states, first_read_text, shown_state
from cnep.sim import scene as S
from cnep.sim.drawing import Drawing, Shape
from cnep.sim.episode import EpisodeResult

APPLICATION_ID = "cnep_sim"
GRIPPER = f"{L.EE}/gripper"
GRIPPER_HALF = (S.GRIPPER_HALF_WIDTH, S.PALM_HALF[1], (S.PALM_HALF[2] * 2 + S.FINGER_HALF[2] * 2) / 2)
GRIPPER_CENTRE = (0.0, 0.0, S.PALM_HALF[2] - GRIPPER_HALF[2])  # the palm's top and the fingers' bottom, as one box
CONTACT_COLOR = (230, 40, 40)


def write_episode(path: Path, name: str, ep: EpisodeResult, n_experts: int, drawing: Drawing) -> Path:
    """Write episode `ep` (run with its frames recorded), drawn as `drawing` says, to the .rrd `path`, listed in the
    viewer as `name`."""
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=name)
    stream = rec.binary_stream()
    rec.send_recording_name(name)
    rec.send_blueprint(L.blueprint(n_experts, camera=True))
    _scene(rec, drawing)
    obj = f"{L.WORLD}/{drawing.obj.name}"
    rec.log(L.EE_PATH, rr.LineStrips3D([ep.states[:, :3]], colors=[L.PATH_COLOR]), static=True)
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(n_experts), colors=L.expert_colors(n_experts)), static=True)
    rec.log(L.ACTIVE_EXPERT, active_expert_states(n_experts), static=True)
    shown = None
    for k in range(len(ep.states)):
        at_step(rec, k)
        for shape in drawing.changes.get(k, ()):
            rec.log(f"{L.WORLD}/{shape.name}", boxes(shape))
        rec.log(L.CAMERA, rr.Image(ep.frames[k]))
        rec.log(L.EE, rr.Transform3D(translation=ep.states[k, :3], quaternion=ep.states[k, 3:7]))
        rec.log(obj, rr.Transform3D(translation=ep.object_poses[k, :3], quaternion=ep.object_poses[k, 3:]))
        if k < len(ep.gates):  # a read of the policy (every step online, the first only when planned)
            shown = log_policy_read(rec, k, ep.gates, ep.experts, ep.predicted, shown)
        if k in drawing.notes:
            note = drawing.notes[k]
            rec.log(L.SWITCH_LOG, rr.TextLog(f"step {k}: {note.text}", level="WARN"))
            if note.mark:
                rec.log(f"{GRIPPER}/contact", rr.Points3D([GRIPPER_CENTRE], radii=0.02, colors=[CONTACT_COLOR]))
    rec.log(L.SWITCH_LOG, rr.TextLog(f"outcome: {drawing.outcome}", level="INFO" if ep.success else "WARN"))
    rec.flush()
    rec.disconnect()
    return write_output(path, stream.read(flush=True) or b"")


def log_policy_read(rec, k: int, gates, experts, predicted, shown: str | None) -> str | None:
    """Log the policy's read at step k: the gate, the predicted waypoints in the active expert's colour, the active
    expert where it changes from `shown` (returned, as now shown), the first read at step 0 and a switch after it."""
    import rerun as rr

    state, color = shown_state(gates[k], int(experts[k]))
    rec.log(L.GATES, rr.Scalars(gates[k]))
    rec.log(L.PREDICTION, rr.LineStrips3D([predicted[k]], colors=[color]))
    if state != shown:
        rec.log(L.ACTIVE_EXPERT, rr.StateChange(state=state))
    if k == 0:
        sure = gates[0][experts[0]] >= L.SURE_GATE
        rec.log(L.SWITCH_LOG, rr.TextLog(first_read_text(gates[0], sure), level="INFO"))
    elif experts[k] != experts[k - 1]:
        text = f"step {k} ({k * S.CONTROL_PERIOD_S:.2f} s): switch {experts[k - 1]} -> {experts[k]}"
        rec.log(L.SWITCH_LOG, rr.TextLog(text, level="INFO"))
    return state


def at_step(rec, k: int) -> None:
    """Set the recording's frame and time lines to control step k."""
    rec.set_time(L.TIMELINE_FRAME, sequence=k)
    rec.set_time(L.TIMELINE_TIME, duration=k * S.CONTROL_PERIOD_S)


def boxes(shape: Shape):
    """`shape` as Rerun boxes."""
    import rerun as rr

    return rr.Boxes3D(
        centers=np.asarray(shape.centres, np.float32).reshape(-1, 3),
        half_sizes=np.asarray(shape.half_sizes, np.float32).reshape(-1, 3),
        colors=[shape.rgb],
        labels=list(shape.labels) or None,
        fill_mode="solid" if shape.solid else None,
    )


def _scene(rec, drawing: Drawing) -> None:
    """The static bodies: the drawing's shapes, its object's shape and the gripper's."""
    import rerun as rr

    rec.log(L.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for shape in (*drawing.shapes, drawing.obj):
        rec.log(f"{L.WORLD}/{shape.name}", boxes(shape), static=True)
    grip_rgb = tuple(round(255 * c) for c in S.GRIPPER_RGBA[:3])
    rec.log(GRIPPER, rr.Boxes3D(centers=[GRIPPER_CENTRE], half_sizes=[GRIPPER_HALF], colors=[grip_rgb]), static=True)
