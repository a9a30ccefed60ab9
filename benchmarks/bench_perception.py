"""Perception speed: frames/s of a naive eager loop, the project default and every backend, against the CPU's limit.

Run on demand (uses every core; do not run it next to other heavy work):
    python -m benchmarks.bench_perception [--frames 64] [--threads N] [--repeats 3]

Measures in one run: (a) a naive per-frame eager torchvision loop, (b) the project's default path
(FeatureExtractor with backend `auto`), (c) every other backend, and the CPU's fp32 matmul GFLOP/s.
Reports the ratio b/a and the fraction of the matmul limit each path reaches, counting 0.6 GFLOP per
224x224 frame for MobileNet-v2's features. All paths include resizing the 640x480 frames to 224x224.
Then the extract stage's path from JPEG bytes (q90), decoding all frames first vs decoding the next
batch while the current one runs through the network.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch
from torchvision.models import mobilenet_v2
from torchvision.transforms.v2 import functional as tvf

from cnep.perception import FeatureExtractor, available_backends
from cnep.perception.constants import DEFAULT_BATCH_SIZE, IMAGE_SIZE, IMAGENET_MEAN, IMAGENET_STD
from cnep.pipeline.extract.stage import decode_batch, features_of_frames

GFLOP_PER_FRAME = 0.6  # MobileNet-v2 features at 224x224: ~0.3 G multiply-adds
FRAME_HW = (480, 640)  # a typical camera frame
MATMUL_SIZE = 2048


def best_seconds(fn: Callable[[], object], repeats: int) -> float:
    """The fastest of `repeats` timed calls after one warm-up call, in seconds."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def matmul_gflops(repeats: int, threads: int) -> dict[str, float]:
    """Measured fp32 matmul GFLOP/s of square MATMUL_SIZE matrices with each available BLAS.

    torch (MKL) and ONNX Runtime (MLAS) reach very different fractions of the same core's peak (MKL's
    kernels are not tuned for AMD cores), so the compute limit is the best of them, not one library's figure.
    """
    rng = np.random.default_rng(0)
    a, b = (rng.standard_normal((MATMUL_SIZE, MATMUL_SIZE), dtype=np.float32) for _ in range(2))
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    calls = {"torch": lambda: torch.mm(ta, tb)}
    if "onnxruntime" in available_backends():
        session = _onnx_matmul_session(threads)
        calls["onnxruntime"] = lambda: session.run(None, {"a": a, "b": b})
    flop = 2 * MATMUL_SIZE**3
    return {name: flop / best_seconds(call, repeats + 2) / 1e9 for name, call in calls.items()}


def _onnx_matmul_session(threads: int) -> object:
    import onnxruntime as ort
    from onnx import TensorProto, helper

    shape = [MATMUL_SIZE, MATMUL_SIZE]
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["a", "b"], ["c"])],
        "matmul",
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape) for n in "ab"],
        [helper.make_tensor_value_info("c", TensorProto.FLOAT, shape)],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def synthetic_frames(n: int, seed: int = 0) -> np.ndarray:
    """(n, 480, 640, 3) uint8 smooth random scenes (upsampled noise), like camera frames rather than white noise."""
    rng = np.random.default_rng(seed)
    coarse = torch.from_numpy(rng.integers(0, 256, (n, 3, 15, 20)).astype(np.float32))  # (n, 3, 15, 20)
    frames = torch.nn.functional.interpolate(coarse, size=FRAME_HW, mode="bilinear", align_corners=False)
    return frames.clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).contiguous().numpy()  # (n, 480, 640, 3)


def naive_loop(frames: np.ndarray) -> Callable[[], object]:
    """The baseline: torchvision eager model, one frame at a time, torchvision resize and normalisation."""
    features = mobilenet_v2(weights=None).features.eval()

    def run() -> list[torch.Tensor]:
        out = []
        with torch.no_grad():
            for frame in frames:
                x = torch.from_numpy(frame).permute(2, 0, 1)  # (3, 480, 640) uint8
                x = tvf.resize(x, [IMAGE_SIZE, IMAGE_SIZE], antialias=True).float() / 255.0
                x = tvf.normalize(x, list(IMAGENET_MEAN), list(IMAGENET_STD))  # (3, 224, 224)
                out.append(features(x[None]).mean(dim=(2, 3)))  # (1, 1280)
        return out

    return run


def extractor_path(frames: np.ndarray, backend: str, threads: int, batch_size: int) -> Callable[[], object]:
    """The project's path for `backend`: random weights (same cost as any weights), calibrated on the frames."""
    extractor = FeatureExtractor("random", backend=backend, threads=threads, batch_size=batch_size)
    extractor.calibrate(frames[:8])
    return lambda: extractor(frames)


def jpeg_frames(frames: np.ndarray, quality: int = 90) -> list[bytes]:
    """JPEG bytes of (N, H, W, 3) uint8 RGB frames, as a demonstration file stores them."""
    encoded = [
        cv2.imencode(".jpg", cv2.cvtColor(f, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])[1] for f in frames
    ]
    return [e.tobytes() for e in encoded]


def stage_paths(frames: np.ndarray, threads: int, batch_size: int) -> dict[str, Callable[[], object]]:
    """The extract stage's JPEG -> features path, decoding up front vs overlapped with inference."""
    extractor = FeatureExtractor("random", backend="auto", threads=threads, batch_size=batch_size)
    extractor.calibrate(frames[:8])
    jpegs, src = jpeg_frames(frames), Path("benchmark.mcap")
    return {
        "(d) JPEG: decode all, then infer": lambda: extractor.features(decode_batch(jpegs, 0, len(jpegs), src)),
        "(d) JPEG: decode overlapped (stage)": lambda: features_of_frames(jpegs, extractor, src),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=64, help="frames per timed pass (default 64)")
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="CPU threads (default: all cores)")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=DEFAULT_BATCH_SIZE,
        help=f"frames per forward pass of the project paths (default {DEFAULT_BATCH_SIZE})",
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed passes per path, best kept (default 3)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    frames = synthetic_frames(args.frames)

    matmul = matmul_gflops(args.repeats, args.threads)
    gflops = max(matmul.values())
    limit_fps = gflops / GFLOP_PER_FRAME
    default = available_backends()[0]
    paths = {
        "(a) naive per-frame eager loop": naive_loop(frames),
        f"(b) project default [{default}]": extractor_path(frames, "auto", args.threads, args.batch_size),
    }
    for backend in available_backends()[1:]:
        paths[f"(c) backend {backend}"] = extractor_path(frames, backend, args.threads, args.batch_size)

    print(
        f"torch {torch.__version__}, {args.threads} threads, {args.frames} frames of {FRAME_HW[1]}x{FRAME_HW[0]}, "
        f"batch size {args.batch_size}, best of {args.repeats}"
    )
    print(
        f"fp32 matmul {MATMUL_SIZE}x{MATMUL_SIZE} GFLOP/s: "
        + ", ".join(f"{name} {value:.1f}" for name, value in matmul.items())
    )
    print(
        f"compute limit: best matmul {gflops:.1f} GFLOP/s -> {limit_fps:.1f} frames/s at {GFLOP_PER_FRAME} GFLOP/frame"
    )
    fps = {}
    for name, run in paths.items():
        fps[name] = args.frames / best_seconds(run, args.repeats)
        print(
            f"{name:<40} {fps[name]:7.1f} frames/s  {fps[name] * GFLOP_PER_FRAME:6.1f} GFLOP/s  "
            f"{fps[name] / limit_fps:5.1%} of limit"
        )
    for name, run in stage_paths(frames, args.threads, args.batch_size).items():
        fps[name] = args.frames / best_seconds(run, args.repeats)
        print(f"{name:<40} {fps[name]:7.1f} frames/s")
    naive, project = list(fps.values())[:2]
    print(f"ratio b/a (project default / naive loop): {project / naive:.2f}x")
    after = max(matmul_gflops(args.repeats, args.threads).values())
    print(f"best fp32 matmul again after the runs: {after:.1f} GFLOP/s (a large change means a noisy machine)")


if __name__ == "__main__":
    main()
