"""Stage `replay`: a checkpoint + trajectory MCAP files -> a Rerun .rrd of the gate's decisions, step by step.

`stage` conditions the model online on each recording and logs it; `layout` holds the timelines,
entity paths, colours and the blueprint.
"""

from cnep.pipeline._lazy import stage_attribute


def __getattr__(name: str) -> object:
    return stage_attribute(__name__, name)
