"""Stage `export`: a checkpoint -> a policy folder that runs without torch (`stage`); a checkpoint as a torch
`runtime.Policy` (`policy.checkpoint_policy`); the model's ONNX graphs (`graphs`).
"""

from cnep.pipeline._lazy import stage_attribute


def __getattr__(name: str) -> object:
    return stage_attribute(__name__, name)
