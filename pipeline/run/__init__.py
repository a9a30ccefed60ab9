"""Stage `run`: a policy (exported folder or checkpoint) stepped through demonstration recordings as a robot loop
would step it, into Rerun, with a summary of the step times (`stage`).
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__, {"config": ("RunConfig", "policy_kind"), "stage": ("open_policy", "run", "summarise", "summary_path")}
)
