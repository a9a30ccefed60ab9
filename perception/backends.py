"""Inference backends for a FeatureNet: torch on a CUDA GPU, eager channels-last torch, traced+frozen torch,
ONNX Runtime, OpenVINO.

Each backend is built from the same module and returns a runner: uint8 (N, 224, 224, 3) -> float32 (N, 1280).
The ONNX export (seconds) is cached on disk by content (the weights' sha256, opset and torch version),
see `onnx_model`; ONNX Runtime and OpenVINO both run that graph (or its int8 quantisation). ONNX Runtime
sessions never spin idle threads: a spinning session on a shared machine burns the cores its neighbours
need (benchmarks/bench_threads.py); OpenVINO's idle threads sleep.
"""

from __future__ import annotations

import copy
import hashlib
import importlib.util
import io
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cnep.outputs import write_atomically
from cnep.perception.constants import BACKEND_MODULES, BACKENDS, CACHE_ENV_VAR, IMAGE_SIZE, ONNX_OPSET
from cnep.perception.errors import PerceptionError
from cnep.runtime.sessions import onnxruntime_graph, openvino_graph

Runner = Callable[[np.ndarray], np.ndarray]
INSTALL_HINT = "onnxruntime needs: pip install 'cnep-pipeline[onnx]'; openvino: pip install 'cnep-pipeline[openvino]'"


def available_backends() -> list[str]:
    """Backends usable in this environment, fastest first (`cuda` needs a GPU that torch sees, ONNX Runtime
    the `onnx` extra, OpenVINO the `openvino` extra)."""
    usable = {
        "cuda": torch.cuda.is_available(),
        **{
            name: all(importlib.util.find_spec(module) is not None for module in modules)
            for name, modules in BACKEND_MODULES.items()
        },
    }
    return [name for name in BACKENDS if usable.get(name, True)]


def build_runner(backend: str, net: nn.Module, threads: int | None = None, cache_key: str | None = None) -> Runner:
    """A runner for `backend` (one of BACKENDS, or `auto` for the fastest available) from eval-mode `net`.

    threads: intra-op threads (None: the library's default); cache_key: what identifies `net`'s weights
    (their sha256), so that ONNX Runtime reuses a cached export; None exports afresh.
    """
    if backend == "auto":
        backend = available_backends()[0]
    if backend not in available_backends():
        raise PerceptionError(
            f"backend {backend!r} is not available; choose one of {available_backends()} or `auto` ({INSTALL_HINT})"
        )
    net = net.eval()
    if backend == "onnxruntime":
        return onnxruntime_runner(onnx_model(net, cache_key), threads)
    if backend == "openvino":
        return openvino_runner(onnx_model(net, cache_key), threads)
    builders = {"cuda": _cuda, "eager": _eager, "torchscript": _torchscript}
    return _with_torch_threads(builders[backend](net, threads), threads)


def _with_torch_threads(run: Runner, threads: int | None) -> Runner:
    """`run` with torch's intra-op threads at `threads` during each call (None: as they are), restored after it:
    the count is process-wide, and the small models that run after extraction in the same process (the
    demo's training, replay and summary) are fastest on one thread."""
    if threads is None:
        return run

    def threaded(pixels: np.ndarray) -> np.ndarray:
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return run(pixels)
        finally:
            torch.set_num_threads(before)

    return threaded


def _example_input() -> torch.Tensor:
    return torch.zeros(2, IMAGE_SIZE, IMAGE_SIZE, 3, dtype=torch.uint8)  # (2, 224, 224, 3)


def _eager(net: nn.Module, threads: int | None) -> Runner:
    net = copy.deepcopy(net).to(memory_format=torch.channels_last)  # oneDNN's fast layout, no compilation

    def run(pixels: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return net(torch.from_numpy(pixels)).numpy()  # (N, 1280)

    return run


def cuda_device() -> torch.device:
    """This process's GPU: LOCAL_RANK (as torchrun sets it) modulo the visible devices, else the first."""
    return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")) % torch.cuda.device_count())


def _cuda(net: nn.Module, threads: int | None) -> Runner:
    """fp32 on this process's GPU with TF32 convolutions off, so the features are the CPU's to float32 rounding
    (TF32 is faster but far less exact: benchmarks/bench_perception.py)."""
    device = cuda_device()
    net = copy.deepcopy(net).to(device, memory_format=torch.channels_last)

    def run(pixels: np.ndarray) -> np.ndarray:
        with torch.inference_mode(), torch.backends.cudnn.flags(enabled=True, allow_tf32=False):
            return net(torch.from_numpy(pixels).to(device)).cpu().numpy()  # (N, 1280)

    return run


def _torchscript(net: nn.Module, threads: int | None) -> Runner:
    net = copy.deepcopy(net).to(memory_format=torch.channels_last)
    with warnings.catch_warnings():
        # torch 2.9+ flags TorchScript as deprecated; it remains the fastest torch-only CPU path here.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*deprecated.*")
        with torch.inference_mode():
            frozen = torch.jit.freeze(torch.jit.trace(net, _example_input()))
            frozen = torch.jit.optimize_for_inference(frozen)  # folds batch norms, oneDNN convolutions

    def run(pixels: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return frozen(torch.from_numpy(pixels)).numpy()  # (N, 1280)

    return run


def onnx_model(net: nn.Module, cache_key: str | None = None) -> bytes:
    """The ONNX graph of `net` (uint8 pixels -> features), from the disk cache when `cache_key` was exported before.

    The cache file is named by the sha256 of (cache_key, opset, torch version), so changed weights or a
    new exporter never reuse a stale graph; it is written under a temporary name and renamed when complete.
    """
    identity = f"{cache_key}|opset={ONNX_OPSET}|torch={torch.__version__}"
    path = None if cache_key is None else cache_path("featurenet", identity)
    if path is not None and path.is_file():
        return path.read_bytes()
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        # The dynamo exporter needs onnxscript; the TorchScript exporter handles this plain CNN exactly.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*(legacy|deprecated|removed).*")
        torch.onnx.export(
            net,
            (_example_input(),),
            buffer,
            dynamo=False,
            input_names=["pixels"],
            output_names=["features"],
            dynamic_axes={"pixels": {0: "n"}, "features": {0: "n"}},
            opset_version=ONNX_OPSET,
        )
    if path is not None:
        write_cache_file(path, buffer.getvalue())
    return buffer.getvalue()


def onnx_cache_dir() -> Path:
    """Where exported graphs are kept: $CNEP_CACHE_DIR/onnx, else $XDG_CACHE_HOME (or ~/.cache)/cnep/onnx."""
    root = os.environ.get(CACHE_ENV_VAR)
    if root:
        return Path(root) / "onnx"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "cnep" / "onnx"


def cache_path(name: str, identity: str) -> Path:
    """The cache file for `name` made from `identity` (all it depends on): its sha256 is in the file name."""
    return onnx_cache_dir() / f"{name}-{hashlib.sha256(identity.encode()).hexdigest()[:32]}.onnx"


def write_cache_file(path: Path, data: bytes) -> None:
    """Cache `data` at `path`: written beside it under a temporary name, then renamed (readers never see half a
    file)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, data)
    except OSError:  # a read-only or full cache only costs the export next time
        pass


def onnxruntime_runner(model: bytes, threads: int | None) -> Runner:
    """A runner over ONNX graph `model` (input `pixels`, output `features`): fp32 or its int8 quantisation."""
    graph = onnxruntime_graph(model, threads, onnx_providers())

    def run(pixels: np.ndarray) -> np.ndarray:
        return graph({"pixels": pixels})[0]  # (N, 1280) float32

    return run


def onnx_providers() -> list:
    """ONNX Runtime's CUDA provider (on GPU LOCAL_RANK, as torchrun sets it) first when this onnxruntime build has
    it and a GPU is visible, then the CPU."""
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers() and torch.cuda.is_available():
        return [("CUDAExecutionProvider", {"device_id": cuda_device().index}), "CPUExecutionProvider"]
    return ["CPUExecutionProvider"]


def openvino_runner(model: bytes, threads: int | None) -> Runner:
    """A runner over ONNX graph `model` (input `pixels`, output `features`) on OpenVINO's CPU plugin: fp32 or int8
    QDQ."""
    graph = openvino_graph(model, threads)

    def run(pixels: np.ndarray) -> np.ndarray:
        return graph({"pixels": pixels})[0]  # (N, 1280) float32, a copy

    return run
