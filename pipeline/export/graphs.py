"""The model's encoder and decoder (models.online.Encoder, Decoder) as ONNX graphs, and a check that they agree.

Both graphs take any number of rows: the encoder any number of context points N, the decoder any number of
queries M (dynamic axes). Input and output names are the runtime's (runtime.exported). The check runs each
graph on ONNX Runtime against torch on seeded random inputs before anything is written.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import torch
from torch import nn

from cnep.models import CNEP
from cnep.models.online import TorchNetwork
from cnep.perception.constants import ONNX_OPSET
from cnep.runtime.exported import (
    DECODER_INPUTS,
    DECODER_OUTPUTS,
    ENCODER_INPUT,
    ENCODER_OUTPUT,
    ExportedNetwork,
)
from cnep.runtime.sessions import onnxruntime_graph

CHECK_TOLERANCE = 1e-4  # max |onnx - torch| accepted on normalised outputs (fp32 kernels differ by ~1e-6)


def to_onnx(module: nn.Module, example: tuple[torch.Tensor, ...], inputs, outputs, dynamic: dict) -> bytes:
    """`module` traced on `example` into ONNX bytes (opset ONNX_OPSET) with named, dynamic axes."""
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode():
        # The dynamo exporter needs onnxscript; the TorchScript exporter handles these MLPs exactly.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*(legacy|deprecated|removed|Converting a tensor).*")
        warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)
        torch.onnx.export(
            module.eval(),
            example,
            buffer,
            dynamo=False,
            input_names=list(inputs),
            output_names=list(outputs),
            dynamic_axes=dynamic,
            opset_version=ONNX_OPSET,
        )
    return buffer.getvalue()


def model_graphs(model: CNEP) -> tuple[bytes, bytes]:
    """(encoder, decoder) ONNX graphs of `model`, checked against torch (`check_graphs`)."""
    network = TorchNetwork(model)
    lay, H = model.config.columns, model.config.latent_dim
    obs = torch.zeros(3, 1 + lay.obs_dim)  # (N, 1 + obs_dim)
    r, query = torch.zeros(1, H), torch.zeros(4, 1 + lay.query_dim)  # (1, H), (M, 1 + query_dim)
    encoder = to_onnx(network.encoder, (obs,), [ENCODER_INPUT], [ENCODER_OUTPUT], {ENCODER_INPUT: {0: "n"}})
    decoder = to_onnx(
        network.decoder,
        (r, query),
        DECODER_INPUTS,
        DECODER_OUTPUTS,
        {DECODER_INPUTS[1]: {0: "m"}, DECODER_OUTPUTS[1]: {1: "m"}, DECODER_OUTPUTS[2]: {1: "m"}},
    )
    check_graphs(network, ExportedNetwork(onnxruntime_graph(encoder, 1), onnxruntime_graph(decoder, 1)), model)
    return encoder, decoder


def check_graphs(torch_network: TorchNetwork, onnx_network: ExportedNetwork, model: CNEP, seed: int = 0) -> float:
    """Max |onnx - torch| over seeded inputs of 1 and 7 rows; a RuntimeError (a bug, not the user's) if over
    CHECK_TOLERANCE."""
    rng = np.random.default_rng(seed)
    lay, H = model.config.columns, model.config.latent_dim
    worst = 0.0
    for n in (1, 7):
        obs = rng.standard_normal((n, 1 + lay.obs_dim), dtype=np.float32)
        obs[:, 0] = rng.uniform(0, 1, n)
        worst = max(worst, float(np.abs(onnx_network.encode(obs) - torch_network.encode(obs)).max()))
        r = rng.standard_normal((1, H), dtype=np.float32)
        query = rng.standard_normal((n, 1 + lay.query_dim), dtype=np.float32)
        query[:, 0] = np.linspace(0, 1, n)
        for a, b in zip(onnx_network.decode(r, query), torch_network.decode(r, query)):
            worst = max(worst, float(np.abs(a - b).max()))
    if not worst <= CHECK_TOLERANCE:
        raise RuntimeError(
            f"the exported graphs differ from the torch model by {worst:.3g} (more than {CHECK_TOLERANCE}); this "
            f"onnxruntime/torch pair exports them wrongly: report it with their versions"
        )
    return worst
