"""The CNMP that matches a CNEP: one expert, widened until it has the CNEP's parameter count.

The paper compares CNEP with a CNMP "of a similar number of parameters" (the authors widened their
CNMP's decoder to [158, 158] for d = 2). Here the encoder (shared by both models) is kept and only the
single expert's hidden layers are widened, to the smallest width whose count reaches the CNEP's, for any
columns (synthetic 1-column, motion, 1288-d scene).
"""

from __future__ import annotations

import dataclasses

import torch

from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig
from cnep.models.errors import ConfigError

MAX_WIDTH = 8192


def parameter_count(config: CNEPConfig) -> int:
    """Trainable parameters of the network `config` builds (counted on the meta device: no memory)."""
    with torch.device("meta"):
        return sum(p.numel() for p in CNEP(config).parameters())


def matched_cnmp(config: CNEPConfig) -> CNEPConfig:
    """A one-expert config with the encoder of `config` and (one width step above) `config`'s parameter count.

    The expert keeps `config`'s depth; the loss coefficients are the CNMP's defaults.
    """
    depth = len(config.expert_widths)
    if depth == 0:
        raise ConfigError("matched_cnmp widens the expert's hidden layers; a config with expert_widths=() has none.")

    def cnmp(width: int) -> CNEPConfig:
        return dataclasses.replace(
            config, n_experts=1, expert_widths=(width,) * depth, a_rec=None, a_batch=None, a_ind=None
        )

    target = parameter_count(config)
    lo, hi = 1, MAX_WIDTH
    while lo < hi:  # the smallest width whose count reaches the target
        mid = (lo + hi) // 2
        if parameter_count(cnmp(mid)) < target:
            lo = mid + 1
        else:
            hi = mid
    return cnmp(lo)
