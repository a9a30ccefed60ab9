"""Seeded random weights made useful: low-pass kernels and a calibration, so that their features tell scenes apart
and keep where things are and what colour they are.

Three problems, three fixes (measurements in docs/results.md):

1. Flat regions lost. torchvision initialises each 3x3 kernel with weights of random sign, so every kernel is a
   random high-pass filter: across the network's 17 blocks a flat region (a coloured tile, an object's face) cancels
   out and only its edges and the sensor's noise come through. Fix (`low_pass`, part of the seeded weights): the
   first convolution's kernels become a positive spatial kernel times colour weights of either sign, and the
   depthwise kernels of the early blocks (up to LOW_PASS_CHANNELS channels, at 112 to 14 pixels) take their
   weights' magnitudes, so colour differences pass and the spatial filters smooth. The later blocks keep kernels
   of either sign: made low-pass too, they keep less and their int8 rounding error grows several-fold.
2. Dead features. A freshly initialised MobileNet-v2 keeps torchvision's running statistics (mean 0,
   variance 1) in every batch norm while its random convolutions shrink the signal layer after layer:
   in eval mode the 1280-d features come out below 1e-5. Fix: re-estimate each batch norm's running
   mean and variance on frames of the recordings (as after any change of input distribution, "AdaBN").
3. Chaotic features. With statistics re-estimated alone, every layer is re-centred, and a deep random
   ReLU network in that regime decorrelates its inputs: a 2-pixel shift of one scene moves the
   features as far as a different scene does. Fix: a positive shift ACTIVATION_BIAS (in units of the
   layer's standard deviation) in every batch norm that feeds a ReLU6, set before the statistics are
   re-estimated. At 3 the units sit in the middle of ReLU6's range (0 to 6) and work in its linear part within
   three standard deviations either way, the classic "ordered" regime of random networks, where nearby inputs
   stay nearby and different scenes stay apart.

The calibration changes only batch-norm parameters and buffers; the convolutions keep their seeded values. The new
values change the weights' sha256, so the identity written into trajectory files names them exactly.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch
from torch import nn
from torchvision.models.mobilenetv2 import InvertedResidual
from torchvision.ops.misc import Conv2dNormActivation

from cnep.perception.errors import PerceptionError

ACTIVATION_BIAS = 3.0  # batch-norm shift before each ReLU6, in standard deviations (measured: docs/results.md)
LOW_PASS_CHANNELS = 64  # the blocks whose depthwise kernels `low_pass` makes low-pass (measured: docs/results.md)


def low_pass(features: nn.Module, channels: int = LOW_PASS_CHANNELS) -> None:
    """Make the early 3x3 kernels of MobileNet-v2 `features` (seeded random weights) low-pass, in place: the first
    convolution's kernel for output o and colour c becomes a * k / mean(k), with a the sign of its centre weight
    times its weights' mean magnitude and k (3x3) the mean magnitude over the colours of o's weights; the depthwise
    kernels of the blocks of at most `channels` channels take their weights' magnitudes."""
    first = features[0][0]  # Conv2dNormActivation(3, 32, 3x3, stride 2)'s convolution
    with torch.no_grad():
        w = first.weight  # (32, 3, 3, 3)
        kernel = w.abs().mean(1, keepdim=True)  # (32, 1, 3, 3)
        colour = torch.sign(w[:, :, 1:2, 1:2]) * w.abs().mean((2, 3), keepdim=True)  # (32, 3, 1, 1)
        w.copy_(colour * kernel / kernel.mean((2, 3), keepdim=True))
        for block in features:
            if isinstance(block, InvertedResidual) and block.out_channels <= channels:
                for module in block.modules():
                    if isinstance(module, nn.Conv2d) and module.groups > 1:  # the depthwise 3x3
                        module.weight.abs_()


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
