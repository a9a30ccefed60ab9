"""ONNX graphs run by ONNX Runtime or OpenVINO on the CPU: named inputs in, the outputs as a list, in order.

ONNX Runtime sessions never spin idle threads: a spinning session on a shared machine burns the cores its
neighbours need; OpenVINO's idle threads sleep. Both take `threads` intra-op threads (None: one per core).
The libraries are imported when a graph is loaded, not with this module. `load_graph` turns whatever a backend
raises while loading or running a graph (a damaged file, external data outside its folder, inputs it does not take)
into one PolicyError naming the file.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from cnep.runtime.constants import BACKENDS, DEFAULT_BACKEND
from cnep.runtime.errors import PolicyError

Graph = Callable[[Mapping[str, np.ndarray]], list[np.ndarray]]


def installed_backends() -> list[str]:
    """BACKENDS whose library is installed here, in BACKENDS' order."""
    return [name for name in BACKENDS if importlib.util.find_spec(name) is not None]


def load_graph(model: bytes | str, backend: str = DEFAULT_BACKEND, threads: int | None = None) -> Graph:
    """Graph `model` (ONNX bytes or a file path) on `backend` (one of BACKENDS); what the backend raises loading or
    running it is a PolicyError naming the file."""
    if backend not in BACKENDS:
        raise PolicyError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend not in installed_backends():
        raise PolicyError(f"backend {backend!r} is not installed here; pip install {backend}")
    name = model if isinstance(model, str) else "an ONNX graph"
    try:
        graph = openvino_graph(model, threads) if backend == "openvino" else onnxruntime_graph(model, threads)
    except Exception as exc:  # the backends raise their own classes (pybind11's, RuntimeError, ...)
        raise PolicyError(f"{name}: {backend} cannot load it ({said(exc)}); export the checkpoint again") from None

    def run(inputs: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        try:
            return graph(inputs)
        except Exception as exc:
            raise PolicyError(f"{name}: {backend} cannot run it ({said(exc)}); export the checkpoint again") from None

    return run


def said(exc: Exception) -> str:
    """What a backend's exception says, in one line: its last line that says something (OpenVINO's messages end with
    the reason, after lines of where it was raised), at most 300 characters."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return (lines[-1] if lines else type(exc).__name__)[:300]


def session_options(threads: int | None):
    """ONNX Runtime options: full graph optimisation, `threads` intra-op threads (None: one per core), no spinning."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.intra_op_num_threads = threads or 0  # 0: one thread per physical core
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")  # idle threads sleep, never spin
    options.log_severity_level = 3  # errors only: loading an int8 graph warns about every folded constant
    return options


def onnxruntime_graph(model: bytes | str, threads: int | None, providers: Sequence | None = None) -> Graph:
    """An ONNX Runtime session of `model` on `providers` (None: the CPU)."""
    import onnxruntime as ort

    session = ort.InferenceSession(model, session_options(threads), providers=providers or ["CPUExecutionProvider"])

    def run(inputs: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        return session.run(None, inputs)

    return run


def openvino_config(threads: int | None) -> dict[str, object]:
    """OpenVINO CPU settings: `threads` inference threads (None: one per core) in one stream, unpinned, fp32.

    One stream with the latency hint runs each call on all `threads`, as the ONNX Runtime session does;
    threads are not pinned to cores, so on a shared machine they move to a free core rather than wait for
    a busy one; fp32 inference precision, so CPUs with bf16 units do not silently lower it. OpenVINO's
    idle threads sleep (it has no spinning option to turn off).
    """
    return {
        "INFERENCE_NUM_THREADS": threads or 0,
        "NUM_STREAMS": 1,
        "PERFORMANCE_HINT": "LATENCY",
        "ENABLE_CPU_PINNING": False,
        "INFERENCE_PRECISION_HINT": "f32",
    }


def openvino_graph(model: bytes | str, threads: int | None) -> Graph:
    """`model` compiled by OpenVINO's CPU plugin (fp32 or int8 QDQ)."""
    import openvino as ov

    core = ov.Core()
    compiled = core.compile_model(core.read_model(model), "CPU", openvino_config(threads))
    request = compiled.create_infer_request()
    outputs = compiled.outputs

    def run(inputs: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        result = request.infer(inputs)
        return [result[port] for port in outputs]

    return run
