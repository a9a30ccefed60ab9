"""Stage `export`: a checkpoint -> a policy folder that runs without torch (`stage`); a checkpoint as a torch
`runtime.Policy` (`policy`); the model's ONNX graphs, checked against torch (`graphs`).
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__, {"config": ("ExportConfig",), "stage": ("export",), "policy": ("checkpoint_policy", "load_for_policy")}
)
