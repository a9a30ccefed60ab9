"""CNEP (and CNMP as one expert) on arrays: the model, its loss, training, checkpoints, evaluation.

Takes numpy arrays, never files or images.
"""

from cnep.models.checkpoint import load_checkpoint, read_checkpoint_config, save_checkpoint
from cnep.models.cnep import CNEP, Prediction
from cnep.models.config import CNEPConfig, ColumnRoles, TrainConfig, authors_coefficients
from cnep.models.errors import ConfigError
from cnep.models.matched import matched_cnmp, parameter_count
from cnep.models.train import Trainer, build_model, fit

__all__ = [
    "CNEP",
    "CNEPConfig",
    "ConfigError",
    "ColumnRoles",
    "Prediction",
    "TrainConfig",
    "Trainer",
    "authors_coefficients",
    "build_model",
    "fit",
    "load_checkpoint",
    "matched_cnmp",
    "parameter_count",
    "read_checkpoint_config",
    "save_checkpoint",
]

from cnep.models.online import ConditioningPolicy, ExpertSwitch, OnlineConditioner, OnlineStep  # noqa: E402
from cnep.models.pid import PIDGains, pid_track  # noqa: E402

__all__ += ["ConditioningPolicy", "ExpertSwitch", "OnlineConditioner", "OnlineStep", "PIDGains", "pid_track"]
