"""A closed-loop episode as a Rerun recording, in the replay's layout (pipeline.replay.viewer: its entity paths,
colours and blueprint) with the scene added: the table, the box (its pose over time), the goal, the cue tile, the
gripper as a box on the end effector's pose; the camera frame, the executed path, the predicted waypoints in the
active expert's colour (grey where the gate is unsure), the gate, the active expert, and as log lines the first
read, every switch, the first contact with the box and the outcome.
"""

from __future__ import annotations

from pathlib import Path

import cnep.pipeline.replay.viewer as L
from cnep.outputs import write_atomically
from cnep.pipeline.replay.rerun_log import active_expert_states, first_read_text, shown_state
from cnep.sim import scene as S
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.demonstrator import SIDE_SIGN
from cnep.sim.tasks.obstacle.scoring import ObstacleEpisode

APPLICATION_ID = "cnep_sim"
BOX, TABLE, GOAL, CUE = (f"{L.WORLD}/{name}" for name in ("box", "table", "goal", "cue"))
GRIPPER = f"{L.EE}/gripper"
GRIPPER_HALF = (S.GRIPPER_HALF_WIDTH, S.PALM_HALF[1], (S.PALM_HALF[2] * 2 + S.FINGER_HALF[2] * 2) / 2)
GRIPPER_CENTRE = (0.0, 0.0, S.PALM_HALF[2] - GRIPPER_HALF[2])  # the palm's top and the fingers' bottom, as one box
CONTACT_COLOR = (230, 40, 40)


def write_episode(path: Path, name: str, ep: ObstacleEpisode, n_experts: int) -> Path:
    """Write episode `ep` (run with its frames recorded) to the .rrd `path`, listed in the viewer as `name`."""
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=name)
    stream = rec.binary_stream()
    rec.send_recording_name(name)
    rec.send_blueprint(L.blueprint(n_experts, camera=True))
    _scene(rec, ep)
    rec.log(L.EE_PATH, rr.LineStrips3D([ep.states[:, :3]], colors=[L.PATH_COLOR]), static=True)
    rec.log(L.GATES, rr.SeriesLines(names=L.expert_names(n_experts), colors=L.expert_colors(n_experts)), static=True)
    rec.log(L.ACTIVE_EXPERT, active_expert_states(n_experts), static=True)
    shown = None
    for k in range(len(ep.states)):
        at_step(rec, k)
        rec.log(L.CAMERA, rr.Image(ep.frames[k]))
        rec.log(L.EE, rr.Transform3D(translation=ep.states[k, :3], quaternion=ep.states[k, 3:7]))
        rec.log(BOX, rr.Transform3D(translation=ep.object_poses[k, :3], quaternion=ep.object_poses[k, 3:]))
        if k < len(ep.gates):  # a read of the policy (every step online, the first only when planned)
            shown = log_policy_read(rec, k, ep.gates, ep.experts, ep.predicted, shown)
        if k == ep.contact_step:
            rec.log(L.SWITCH_LOG, rr.TextLog(f"step {k}: the gripper touches the box", level="WARN"))
            rec.log(f"{GRIPPER}/contact", rr.Points3D([GRIPPER_CENTRE], radii=0.02, colors=[CONTACT_COLOR]))
    outcome = "success" if ep.success else "collision" if ep.collision else "missed the goal"
    rec.log(
        L.SWITCH_LOG,
        rr.TextLog(
            f"outcome: {outcome}; passed {ep.side}, min clearance {ep.clearance_m * 100:.1f} cm, "
            f"{ep.distance_to_goal_m * 100:.1f} cm from the goal",
            level="INFO" if ep.success else "WARN",
        ),
    )
    rec.flush()
    rec.disconnect()
    return write_atomically(path, stream.read(flush=True) or b"")


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


def _scene(rec, ep: ObstacleEpisode) -> None:
    """The static bodies: table, goal, cue tile (where it was), box and gripper shapes."""
    import rerun as rr

    rgb = [tuple(round(255 * c) for c in rgba[:3]) for rgba in (S.TABLE_RGBA, O.GOAL_RGBA, O.CUE_RGBA)]
    rec.log(L.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        TABLE, rr.Boxes3D(centers=[(0, 0, -S.TABLE_HALF[2])], half_sizes=[S.TABLE_HALF], colors=[rgb[0]]), static=True
    )
    goal = (O.GOAL_RADIUS, O.GOAL_RADIUS, 0.001)
    rec.log(GOAL, rr.Boxes3D(centers=[(*O.GOAL_XY, 0.001)], half_sizes=[goal], colors=[rgb[1]]), static=True)
    if ep.cue_side is not None:
        cue = (O.CUE_XY[0] * SIDE_SIGN[ep.cue_side], O.CUE_XY[1], 0.001)
        half = (O.CUE_HALF, O.CUE_HALF, 0.001)
        rec.log(CUE, rr.Boxes3D(centers=[cue], half_sizes=[half], colors=[rgb[2]]), static=True)
    box_rgb = tuple(round(255 * c) for c in O.BOX_RGBA[:3])
    rec.log(BOX, rr.Boxes3D(half_sizes=[O.BOX_HALF], colors=[box_rgb], fill_mode="solid"), static=True)
    grip_rgb = tuple(round(255 * c) for c in S.GRIPPER_RGBA[:3])
    rec.log(GRIPPER, rr.Boxes3D(centers=[GRIPPER_CENTRE], half_sizes=[GRIPPER_HALF], colors=[grip_rgb]), static=True)
