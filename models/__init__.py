"""CNEP (and CNMP as one expert) on arrays: the model, its loss, training, checkpoints, evaluation.

Takes numpy arrays, never files or images.
"""

from models.checkpoint import load_checkpoint, read_checkpoint_config, save_checkpoint
from models.cnep import CNEP, Prediction
from models.config import CNEPConfig, Layout, TrainConfig, authors_coefficients
from models.errors import ConfigError
from models.matched import matched_cnmp, parameter_count
from models.train import Trainer, build_model, fit

__all__ = [
    "CNEP",
    "CNEPConfig",
    "ConfigError",
    "Layout",
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

from models.online import ConditioningPolicy, ExpertSwitch, OnlineConditioner, OnlineStep  # noqa: E402
from models.pid import PIDGains, pid_track  # noqa: E402

__all__ += ["ConditioningPolicy", "ExpertSwitch", "OnlineConditioner", "OnlineStep", "PIDGains", "pid_track"]
