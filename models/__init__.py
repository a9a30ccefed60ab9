"""CNEP (and CNMP as one expert) on arrays: the model, its loss, training, checkpoints, evaluation.

Takes numpy arrays, never files or images.
"""

import importlib

# Module -> the public names it defines. A name's module is imported when the name is first used (PEP 562), so
# `cnep.models.config` (the settings `cnep train --help` shows) and `cnep.models.errors` load without torch;
# the pipeline's stage packages hand out their names the same way (cnep.pipeline.exports).
_MODULES = {
    "checkpoint": ("load_checkpoint", "read_checkpoint_config", "save_checkpoint"),
    "cnep": ("CNEP", "Prediction"),
    "config": (
        "CNEPConfig",
        "ColumnRoles",
        "ConditioningOverrides",
        "ConditioningPolicy",
        "TrainConfig",
        "authors_coefficients",
    ),
    "errors": ("ConfigError",),
    "matched": ("matched_cnmp", "parameter_count"),
    "online": ("ExpertSwitch", "OnlineConditioner", "OnlineStep"),
    "pid": ("PIDGains", "pid_track"),
    "schedule": ("Schedule", "schedule_of", "scheduled"),
    "train": ("Trainer", "build_model", "fit"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
