"""Calibration of seeded random weights, so that their features tell scenes apart.

Two problems, two documented fixes (measurements in docs/results.md):

1. Dead features. A freshly initialised MobileNet-v2 keeps torchvision's running statistics (mean 0,
   variance 1) in every batch norm while its random convolutions shrink the signal layer after layer:
   in eval mode the 1280-d features come out around 1e-9. Fix: re-estimate each batch norm's running
   mean and variance on frames of the recordings (as after any change of input distribution, "AdaBN").
2. Chaotic features. With statistics re-estimated alone, every layer is re-centred, and a deep random
   ReLU network in that regime decorrelates its inputs: a 2-pixel shift of one scene moves the
   features as far as a different scene does. Fix: a positive shift ACTIVATION_BIAS (in units of the
   layer's standard deviation) in every batch norm that feeds a ReLU6, set before the statistics are
   re-estimated. Most units then work in the linear part of ReLU6, the classic "ordered" regime of
   random networks, where nearby inputs stay nearby and different scenes stay apart.

Only batch-norm parameters and buffers change; the convolutions keep their seeded values. The new
values change the weights' sha256, so the identity written into trajectory files names them exactly.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch
from torch import nn
from torchvision.ops.misc import Conv2dNormActivation

from cnep.perception.errors import PerceptionError

ACTIVATION_BIAS = 2.0  # batch-norm shift before each ReLU6, in standard deviations (measured: docs/results.md)


def calibrate_random_network(
    net: nn.Module, batches: Iterable[np.ndarray], activation_bias: float = ACTIVATION_BIAS
) -> int:
    """Set the activation bias, then re-estimate batch-norm statistics on uint8 (B, 224, 224, 3) pixel batches.

    `net` is a FeatureNet with seeded random weights. Returns the number of frames used; leaves it in eval mode.
    """
    for block in net.modules():
        if isinstance(block, Conv2dNormActivation):  # conv -> batch norm -> ReLU6
            block[1].bias.data.fill_(activation_bias)
    return recalibrate_batchnorm(net, batches)


def recalibrate_batchnorm(net: nn.Module, batches: Iterable[np.ndarray]) -> int:
    """Replace every BatchNorm2d's running mean/var by their average over `batches` of uint8 (B, 224, 224, 3) pixels.

    Returns the number of frames used; leaves `net` in eval mode.
    """
    norms = [m for m in net.modules() if isinstance(m, nn.BatchNorm2d)]
    momenta = [m.momentum for m in norms]
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None  # cumulative average over all calibration batches, not an exponential one
    seen = 0
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a fixed reduction order: the same frames give bit-identical statistics and hash
    net.train()
    try:
        with torch.no_grad():
            for batch in batches:
                net(torch.from_numpy(np.ascontiguousarray(batch)))  # (B, 1280), only the statistics matter
                seen += len(batch)
    finally:
        torch.set_num_threads(threads)
        net.eval()
        for norm, momentum in zip(norms, momenta):
            norm.momentum = momentum
    if seen < 2:
        raise PerceptionError(f"batch-norm calibration needs at least 2 frames, got {seen}")
    return seen
