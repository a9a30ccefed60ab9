"""The feature network: uint8 RGB (N, 224, 224, 3) -> ImageNet normalisation -> MobileNet-v2 features -> pooling
-> (N, 1280).

Pooling `global` averages each channel over the whole 7 x 7 map, as ImageNet weights were trained: a channel
then says how much of its pattern the frame holds, not where. Seeded random weights have no channel that means
anything on its own, so `cells` gives each channel one cell of the map instead (channel c reads cell c mod 49,
about 26 channels a cell): the same 1280 numbers then keep where things stand, which the demo's behaviours
depend on (measured in docs/results.md).
"""

from __future__ import annotations

import torch
from torch import nn
from torchvision.models import mobilenet_v2

from cnep.perception.constants import ARCHITECTURES, FEATURE_DIM, FEATURE_GRID, IMAGENET_MEAN, IMAGENET_STD
from cnep.perception.errors import PerceptionError


def mobilenet_v2_features() -> nn.Module:
    """A freshly initialised torchvision MobileNet-v2 `features` block (uses the global torch RNG)."""
    return mobilenet_v2(weights=None).features


def cell_mask() -> torch.Tensor:
    """(1280, 49) one-hot: row c picks cell c mod 49 of the flattened 7 x 7 map."""
    cells = FEATURE_GRID * FEATURE_GRID
    return torch.nn.functional.one_hot(torch.arange(FEATURE_DIM) % cells, cells).float()


class FeatureNet(nn.Module):
    """MobileNet-v2 `features` + pooling (`global` or `cells`, see the module docstring), taking raw uint8 NHWC
    pixels.

    The normalisation lives inside the module so every backend (eager, traced, ONNX) runs the very same
    graph from the same uint8 input, and the permute to NCHW yields channels-last memory for free.
    """

    def __init__(self, features: nn.Module, pooling: str = "global") -> None:
        super().__init__()
        if pooling not in ARCHITECTURES:
            raise PerceptionError(f"pooling must be one of {tuple(ARCHITECTURES)}, got {pooling!r}")
        self.features, self.pooling = features, pooling
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1) * 255.0)  # (1, 3, 1, 1)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1) * 255.0)  # (1, 3, 1, 1)
        if pooling == "cells":
            self.register_buffer("cells", cell_mask())  # (1280, 49)

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        x = pixels.permute(0, 3, 1, 2).float()  # (N, 3, 224, 224), channels-last strides
        x = (x - self.mean) / self.std  # ImageNet normalisation on the 0..255 scale
        x = self.features(x)  # (N, 1280, 7, 7)
        if self.pooling == "cells":
            return (x.flatten(2) * self.cells).sum(-1)  # (N, 1280): a mask, not a gather, exports to every backend
        return x.mean(dim=(2, 3))  # (N, 1280)
