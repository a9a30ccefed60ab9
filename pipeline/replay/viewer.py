"""Where the replay puts things in Rerun: timelines, entity paths, expert names and colours, the blueprint.

Import `rerun` lazily (it is slow to import): only `blueprint()` needs it, and imports it when called.
"""

from __future__ import annotations

from collections.abc import Mapping

APPLICATION_ID = "cnep_replay"

# Timelines
TIMELINE_FRAME = "frame"  # sequence: the step index of the recording
TIMELINE_TIME = "time"  # duration: time since the recording's first step

# Entities
CAMERA = "/camera/rgb"  # EncodedImage: the stored JPEG bytes
EE = "/world/ee"  # Transform3D: end-effector pose per step
EE_PATH = "/world/ee_path"  # LineStrips3D, static: the whole recorded path
PREDICTION = "/world/prediction"  # LineStrips3D per step: the active expert's remaining trajectory, in its colour
# (UNSURE_COLOR where the gate is unsure)
GATES = "/gates"  # Scalars, d per step: the gate probabilities, one named, coloured series per expert
ACTIVE_EXPERT = "/active_expert"  # StateChange at the first step and where the shown state changes: the active
# expert, or UNSURE where the gate is unsure (+ StateConfiguration)
SWITCH_LOG = "/log/experts"  # TextLog: the first read (step 0), then one line per switch
WORLD = "/world"
TIMING = "/timing"  # `cnep run` only: how long each policy step took against the frame period
STEP_TIME = "/timing/step_ms"  # Scalars per step: the milliseconds the policy's step took
FRAME_PERIOD = "/timing/frame_period_ms"  # Scalars per step: the recording's frame period, the step's budget

# Expert colours (RGB), cycled when there are more experts than colours.
PALETTE = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)
PATH_COLOR = (200, 200, 200)
# The gate is unsure at a step where its active expert holds less than this probability: the replay and the run
# show such a step as unsure, not as a commitment to that expert (a first read from an ambiguous first frame often is).
SURE_GATE = 0.7
UNSURE = "unsure"  # the active-expert lane's state at steps where the gate is unsure
UNSURE_COLOR = (160, 160, 160)  # that state's colour, and the predicted path's at those steps
GATE_AXIS = (-0.05, 1.05)  # the gate plot's y range: probabilities of exactly 0 and 1 stay clear of the border


def expert_name(e: int, labels: Mapping[int, str] | None = None) -> str:
    """Display name of expert `e` (also the state value of the active-expert lane): `expert 3`, or with what the
    caller knows it stands for, `expert 3 (left-near)`."""
    label = (labels or {}).get(e)
    return f"expert {e} ({label})" if label else f"expert {e}"


def expert_names(n_experts: int, labels: Mapping[int, str] | None = None) -> list[str]:
    return [expert_name(e, labels) for e in range(n_experts)]


def expert_colors(n_experts: int) -> list[tuple[int, int, int]]:
    return [PALETTE[e % len(PALETTE)] for e in range(n_experts)]


def blueprint(n_experts: int, camera: bool = True, timing: bool = False):
    """The replay layout, a pure function of the number of experts, whether there are camera frames and whether
    step times are shown (`cnep run`: a plot of TIMING below the gate).

    Left: the camera (only when the recording has frames) above the 3D view (end-effector pose,
    recorded path, the predicted trajectory in the active expert's colour, grey where the gate is unsure).
    Right: the gate probabilities over time (one named, coloured series per expert, y in GATE_AXIS), the
    active expert as a colour lane (`unsure` where the gate is), and the log of the first read and the
    expert switches (its text only: `step 18 (1.80 s): ...`).
    The recordings list (left panel) and the time panel stay open; the selection panel is collapsed.
    """
    import rerun as rr
    import rerun.blueprint as rrb

    series = rr.SeriesLines(names=expert_names(n_experts), colors=expert_colors(n_experts))
    scene = [rrb.Spatial2DView(origin=CAMERA, name="camera")] if camera else []
    log_columns = rrb.TextLogColumns(  # the text says the step and the time itself: no narrow, cut time column
        timeline_columns=[
            rrb.components.TimelineColumn(TIMELINE_TIME, visible=False),
            rrb.components.TimelineColumn(TIMELINE_FRAME, visible=False),
        ],
        text_log_columns=[
            rrb.components.TextLogColumn("Body"),
            rrb.components.TextLogColumn("EntityPath", visible=False),
            rrb.components.TextLogColumn("LogLevel", visible=False),
        ],
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*scene, rrb.Spatial3DView(origin=WORLD, name="end effector and prediction")),
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=GATES,
                    name=f"gate probabilities ({n_experts} experts)",
                    defaults=[series],
                    axis_y=rrb.ScalarAxis(range=GATE_AXIS),
                ),
                rrb.StateTimelineView(origin=ACTIVE_EXPERT, name="active expert"),
                *([rrb.TimeSeriesView(origin=TIMING, name="step time (ms)")] if timing else []),
                rrb.TextLogView(origin=SWITCH_LOG, name="expert switches", columns=log_columns),
                row_shares=[3, 1, 2, 2] if timing else [3, 1, 2],
            ),
            column_shares=[2, 3],
        ),
        rrb.BlueprintPanel(state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded", timeline=TIMELINE_TIME),
    )
