"""Stage `run`: a policy (exported folder or checkpoint) stepped through demonstration recordings as a robot loop
would step it, into Rerun, with a summary of the step times (`stage`).
"""

from cnep.pipeline._lazy import stage_attribute


def __getattr__(name: str) -> object:
    return stage_attribute(__name__, name)
