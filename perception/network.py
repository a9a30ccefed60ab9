"""The feature network: uint8 RGB (N, 224, 224, 3) -> ImageNet normalisation -> MobileNet-v2 features -> (N, 1280)."""

from __future__ import annotations

import torch
from torch import nn
from torchvision.models import mobilenet_v2

from cnep.perception.constants import IMAGENET_MEAN, IMAGENET_STD


def mobilenet_v2_features() -> nn.Module:
    """A freshly initialised torchvision MobileNet-v2 `features` block (uses the global torch RNG)."""
    return mobilenet_v2(weights=None).features


class FeatureNet(nn.Module):
    """MobileNet-v2 `features` + global average pool, taking raw uint8 NHWC pixels.

    The normalisation lives inside the module so every backend (eager, traced, ONNX) runs the very same
    graph from the same uint8 input, and the permute to NCHW yields channels-last memory for free.
    """

    def __init__(self, features: nn.Module) -> None:
        super().__init__()
        self.features = features
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1) * 255.0)  # (1, 3, 1, 1)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1) * 255.0)  # (1, 3, 1, 1)

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        x = pixels.permute(0, 3, 1, 2).float()  # (N, 3, 224, 224), channels-last strides
        x = (x - self.mean) / self.std  # ImageNet normalisation on the 0..255 scale
        x = self.features(x)  # (N, 1280, 7, 7)
        return x.mean(dim=(2, 3))  # (N, 1280)
