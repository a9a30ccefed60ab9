"""Stage `replay`: a checkpoint + trajectory MCAP files -> a Rerun .rrd of the gate's decisions, step by step.

`stage` checks the inputs and orchestrates; `conditioning` steps the model's online conditioner
through each recording (`decide`); `rerun_log` logs the decisions beside the camera and the pose;
`viewer` holds the timelines, entity paths, colours and the blueprint; `decisions` writes and reads
the decisions file (`read_decisions`).
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__,
    {
        "stage": ("replay",),
        "conditioning": ("Decisions", "decide"),
        "decisions": ("decisions_path", "read_decisions"),
        "rerun_log": ("serve",),
    },
)
