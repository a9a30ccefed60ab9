"""Inference backends for a FeatureNet: eager channels-last torch, traced+frozen torch, ONNX Runtime.

Each backend is built from the same module and returns a runner: uint8 (N, 224, 224, 3) -> float32 (N, 1280).
"""

from __future__ import annotations

import copy
import importlib.util
import io
import warnings
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from perception.constants import BACKENDS, IMAGE_SIZE
from perception.errors import PerceptionError

Runner = Callable[[np.ndarray], np.ndarray]


def available_backends() -> list[str]:
    """Backends usable in this environment, fastest first (ONNX Runtime needs the `onnx` extra)."""
    have_onnx = all(importlib.util.find_spec(m) is not None for m in ("onnx", "onnxruntime"))
    return [name for name in BACKENDS if name != "onnxruntime" or have_onnx]


def build_runner(backend: str, net: nn.Module, threads: int | None = None) -> Runner:
    """A runner for `backend` (one of BACKENDS, or `auto` for the fastest available) from eval-mode `net`."""
    if backend == "auto":
        backend = available_backends()[0]
    if backend not in available_backends():
        raise PerceptionError(f"backend {backend!r} is not available; choose one of {available_backends()} or "
                              f"`auto` (onnxruntime needs: pip install 'cnep-pipeline[onnx]')")
    if threads is not None:
        torch.set_num_threads(threads)  # process-wide: torch has no per-module thread pool
    net = net.eval()
    builders = {"eager": _eager, "torchscript": _torchscript, "onnxruntime": _onnxruntime}
    return builders[backend](net, threads)


def _example_input() -> torch.Tensor:
    return torch.zeros(2, IMAGE_SIZE, IMAGE_SIZE, 3, dtype=torch.uint8)  # (2, 224, 224, 3)


def _eager(net: nn.Module, threads: int | None) -> Runner:
    net = copy.deepcopy(net).to(memory_format=torch.channels_last)  # oneDNN's fast layout, no compilation

    def run(pixels: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return net(torch.from_numpy(pixels)).numpy()  # (N, 1280)

    return run


def _torchscript(net: nn.Module, threads: int | None) -> Runner:
    net = copy.deepcopy(net).to(memory_format=torch.channels_last)
    with warnings.catch_warnings():
        # torch 2.9+ flags TorchScript as deprecated; it remains the fastest torch-only CPU path measured here.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*deprecated.*")
        with torch.inference_mode():
            frozen = torch.jit.freeze(torch.jit.trace(net, _example_input()))
            frozen = torch.jit.optimize_for_inference(frozen)  # folds batch norms, oneDNN convolutions

    def run(pixels: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return frozen(torch.from_numpy(pixels)).numpy()  # (N, 1280)

    return run


def _onnxruntime(net: nn.Module, threads: int | None) -> Runner:
    import onnxruntime as ort

    buffer = io.BytesIO()
    with warnings.catch_warnings():
        # The dynamo exporter needs onnxscript; the TorchScript exporter handles this plain CNN exactly.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*(legacy|deprecated|removed).*")
        torch.onnx.export(net, (_example_input(),), buffer, dynamo=False, input_names=["pixels"],
                          output_names=["features"], dynamic_axes={"pixels": {0: "n"}, "features": {0: "n"}},
                          opset_version=17)
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.intra_op_num_threads = threads or 0  # 0: one thread per physical core
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(buffer.getvalue(), options, providers=["CPUExecutionProvider"])

    def run(pixels: np.ndarray) -> np.ndarray:
        return session.run(None, {"pixels": pixels})[0]  # (N, 1280) float32

    return run
