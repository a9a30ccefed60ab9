"""Thread policy, idle and loaded: training and feature extraction with a second busy process paused or running.

Run on demand (say the machine's load when you quote it):
    python -m benchmarks.bench_threads [--frames 32] [--steps 40] [--rounds 2]

A second process trains a CNEP on one thread without pause (what `cnep evaluate` or the demo's
trainers do beside an extractor). It is paused (SIGSTOP) for the "idle" and resumed (SIGCONT) for the
"loaded" measurement, round after round, so every ratio comes from one run under one background load.
Measured:
- training: `models.Trainer` steps/s (default CNEP, 4 experts) on 1 torch thread (the policy) and on 2;
- extraction, frames/s of 640x480 frames: the naive per-frame eager loop (torch's default threads,
  and one thread), the old default (ONNX
  Runtime, one thread per core, spinning threads), the new default (pipeline.workers.inference_threads
  threads, no spinning), one thread without spinning, int8 (perception.quantisation) on ONNX Runtime
  with the new default's threads, and, when the `openvino` extra is installed, OpenVINO fp32 and int8
  (the same graphs) with those threads; and the int8 features' error against fp32 (cosine, relative L2);
- idle spinning: the CPU time each runtime's session burns while the process sleeps between batches
  (ONNX Runtime with spinning on and off, OpenVINO), with the policy's threads.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import signal
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from benchmarks.bench_perception import extractor_path, naive_loop, synthetic_frames
from cnep.models import CNEPConfig, TrainConfig
from cnep.models.synthetic import make_set
from cnep.models.train import prepare_fit
from cnep.perception import FeatureExtractor, available_backends, resize_frames
from cnep.perception.backends import onnx_model
from cnep.perception.constants import DEFAULT_BATCH_SIZE
from cnep.pipeline.workers import inference_threads
from cnep.runtime.sessions import session_options


def busy_training(parent: int) -> None:
    """The background load: one-thread CNEP training steps until killed or its parent is gone."""
    torch.set_num_threads(1)
    trainer = training_step_fn(seed=1)
    while os.getppid() == parent:
        trainer()


def training_step_fn(seed: int = 0) -> Callable[[], object]:
    data = make_set("multimodal", seed)
    trainer, _ = prepare_fit(
        list(data.train), CNEPConfig(n_experts=4, assignment="paper"), TrainConfig(seed=seed), list(data.val)
    )
    return trainer.train_step


def threaded(fn: Callable[[], object], threads: int) -> Callable[[], object]:
    """`fn` run with `threads` torch threads (restored after)."""

    def run() -> object:
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return fn()
        finally:
            torch.set_num_threads(before)

    return run


def onnx_session_path(frames: np.ndarray, threads: int, spinning: bool) -> Callable[[], object]:
    """FeatureExtractor's ONNX Runtime path with an explicit session: `threads` (0: one per core), spinning on/off."""
    import onnxruntime as ort

    ort.set_default_logger_severity(3)  # the spinning entry is set twice on purpose: no warning
    extractor = FeatureExtractor("random", backend="onnxruntime", threads=1)
    extractor.calibrate(frames[:8])
    options = session_options(threads or None)
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    session = ort.InferenceSession(
        onnx_model(extractor.net, extractor.identity["weights_sha256"]), options, providers=["CPUExecutionProvider"]
    )
    extractor._runner = lambda pixels: session.run(None, {"pixels": pixels})[0]  # the benchmark's own session
    return lambda: extractor(frames)


def int8_path(frames: np.ndarray, threads: int, backend: str) -> tuple[Callable[[], object], dict[str, float]]:
    """The int8 extractor on `backend` (quantised on `frames`) and its feature error against fp32 (ONNX Runtime)
    with the same calibrated weights."""
    fp32 = FeatureExtractor("random", backend="onnxruntime", threads=threads)
    int8 = FeatureExtractor("random", backend=backend, threads=threads, precision="int8")
    for extractor in (fp32, int8):
        extractor.calibrate(frames[:8])
    int8.quantise(frames)
    a, b = fp32(frames), int8(frames)  # (N, 1280) each
    cosine = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    relative = np.linalg.norm(a - b, axis=1) / np.linalg.norm(a, axis=1)
    error = {
        "cosine_min": float(cosine.min()),
        "cosine_median": float(np.median(cosine)),
        "relative_l2_median": float(np.median(relative)),
        "relative_l2_max": float(relative.max()),
    }
    return lambda: int8(frames), error


def idle_cpu_seconds(
    run: Callable[[np.ndarray], object], pixels: np.ndarray, pauses: int = 5, pause_s: float = 0.3
) -> float:
    """CPU seconds this process burns during `pauses` sleeps of `pause_s` s, each right after `run(pixels)`.

    Threads that sleep when idle burn ~0; threads that spin burn up to threads x pause_s per pause.
    """
    run(pixels)
    idle = 0.0
    for _ in range(pauses):
        run(pixels)
        before = resource.getrusage(resource.RUSAGE_SELF)
        time.sleep(pause_s)
        after = resource.getrusage(resource.RUSAGE_SELF)
        idle += (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return idle


def spinning_report(frames: np.ndarray, threads: int) -> str:
    """CPU seconds burnt while idle by each runtime's session with `threads` threads (see idle_cpu_seconds)."""
    import onnxruntime as ort

    from cnep.perception.backends import onnxruntime_runner, openvino_runner

    extractor = FeatureExtractor("random", threads=threads)
    extractor.calibrate(frames[:8])
    graph = onnx_model(extractor.net, extractor.identity["weights_sha256"])
    pixels = resize_frames(frames[:4])  # (4, 224, 224, 3)
    runners = {"ONNX Runtime, no spinning (policy)": onnxruntime_runner(graph, threads)}
    ort.set_default_logger_severity(3)  # the spinning entry is set twice on purpose: no warning
    options = session_options(threads)
    options.add_session_config_entry("session.intra_op.allow_spinning", "1")
    spinning = ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
    runners["ONNX Runtime, spinning"] = lambda x: spinning.run(None, {"pixels": x})
    if "openvino" in available_backends():
        runners["OpenVINO"] = openvino_runner(graph, threads)
    return "; ".join(f"{name} {idle_cpu_seconds(run, pixels):.3f} s" for name, run in runners.items())


def rate(fn: Callable[[], object], units: int) -> float:
    start = time.perf_counter()
    fn()
    return units / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=32)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    frames = synthetic_frames(args.frames)
    step = training_step_fn()
    policy = inference_threads()
    variants: dict[str, tuple[Callable[[], object], int]] = {
        "train, 1 thread (policy)": (threaded(lambda: [step() for _ in range(args.steps)], 1), args.steps),
        "train, 2 threads": (threaded(lambda: [step() for _ in range(args.steps)], 2), args.steps),
        "extract, naive eager loop": (threaded(naive_loop(frames), torch.get_num_threads()), args.frames),
        "extract, naive eager loop, 1 thread": (threaded(naive_loop(frames), 1), args.frames),
        "extract, old default (ORT all cores, spinning)": (onnx_session_path(frames, 0, True), args.frames),
        f"extract, new default (ORT {policy} threads, no spin)": (
            onnx_session_path(frames, policy, False),
            args.frames,
        ),
        "extract, ORT 1 thread, no spin": (onnx_session_path(frames, 1, False), args.frames),
    }
    int8_backends = ["onnxruntime"]
    if "openvino" in available_backends():
        variants[f"extract, OpenVINO fp32 ({policy} threads)"] = (
            extractor_path(frames, "openvino", policy, DEFAULT_BATCH_SIZE),
            args.frames,
        )
        int8_backends.append("openvino")
    for backend in int8_backends:
        int8, error = int8_path(frames, policy, backend)
        variants[f"extract, int8 {backend} ({policy} threads)"] = (int8, args.frames)
        print(f"int8 on {backend} vs fp32 features: " + ", ".join(f"{k} {v:.5f}" for k, v in error.items()))
    print(
        f"CPU time burnt during 5 x 0.3 s idle pauses between batches, {policy} threads: "
        f"{spinning_report(frames, policy)}"
    )
    for fn, _ in variants.values():
        fn()  # warm-up
    load = multiprocessing.get_context("spawn").Process(target=busy_training, args=(os.getpid(),), daemon=True)
    load.start()
    time.sleep(15)  # let it import and start training
    print(f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs")
    rates: dict[tuple[str, str], list[float]] = {}
    try:
        for _ in range(args.rounds):
            for condition in ("idle", "loaded"):
                os.kill(load.pid, signal.SIGSTOP if condition == "idle" else signal.SIGCONT)
                time.sleep(0.5)
                for name, (fn, units) in variants.items():
                    rates.setdefault((name, condition), []).append(rate(fn, units))
    finally:
        os.kill(load.pid, signal.SIGCONT)
        load.kill()
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    median = {key: statistics.median(values) for key, values in rates.items()}
    print(f"{'variant':<52} {'idle':>8} {'loaded':>8}  loaded/idle  (steps/s or frames/s, median of {args.rounds})")
    for name in variants:
        idle, loaded = median[(name, "idle")], median[(name, "loaded")]
        print(f"{name:<52} {idle:8.1f} {loaded:8.1f}  {loaded / idle:6.2f}")
    names = list(variants)
    for condition in ("idle", "loaded"):
        train = median[("train, 1 thread (policy)", condition)] / median[("train, 2 threads", condition)]
        naive, old, new = (median[(names[i], condition)] for i in (2, 4, 5))
        print(
            f"{condition}: training 1 thread / 2 threads {train:.2f}x; extraction new default / old default "
            f"{new / old:.2f}x, new default / naive loop {new / naive:.2f}x"
        )
        for name in names[7:]:
            print(
                f"{condition}:   {name[len('extract, ') :]} / new default fp32 {median[(name, condition)] / new:.2f}x, "
                f"/ naive loop {median[(name, condition)] / naive:.2f}x"
            )


if __name__ == "__main__":
    main()
