"""`cnep extract` across processes: wall time of the stage with --workers 2 against --workers 1 (and --precision int8).

Run on demand (say the machine's load when you quote it):
    python -m benchmarks.bench_extract [--files 4] [--frames 48] [--rounds 2]

Writes `files` demonstration files of `frames` 640x480 JPEG frames (smooth random scenes) into a
temporary folder, calibrates random weights once (saved, so every timed run uses fixed weights and
builds no calibration), then times `pipeline.extract.extract` with force=True for each variant,
round after round (interleaved, so the ratios share the load). Reports frames/s (median over rounds)
and os.getloadavg() before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_perception import jpeg_frames, synthetic_frames
from pipeline.extract.stage import ExtractConfig, extract
from recordings import Demonstration, Episode, write_demonstration


def write_demos(folder: Path, files: int, frames: int) -> list[Path]:
    """`files` demonstrations of `frames` JPEG frames each, with a plausible pose and gripper."""
    paths = []
    for k in range(files):
        pose = np.zeros((frames, 7))
        pose[:, 6] = 1.0  # identity quaternion (x, y, z, w)
        pose[:, 0] = np.linspace(0, 0.3, frames)
        demo = Demonstration(episode=Episode(episode_id=f"bench-{k}", fps=10.0, task="bench", source="synthetic"),
                             timestamps_ns=np.arange(frames, dtype=np.int64) * 100_000_000, pose=pose,
                             gripper=np.linspace(0, 100, frames), frames=jpeg_frames(synthetic_frames(frames, seed=k)))
        paths.append(write_demonstration(folder / f"demo-{k}.mcap", demo))
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=4)
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="cnep-bench-extract-") as tmp:
        root = Path(tmp)
        (root / "demos").mkdir()
        demos = write_demos(root / "demos", args.files, args.frames)
        weights = root / "weights.pt"
        extract(ExtractConfig(inputs=tuple(demos), out=root / "calibrate", weights="random", save_weights=weights,
                              quiet=True))
        variants = {"fp32, 1 worker": {"workers": 1}, "fp32, 2 workers": {"workers": 2},
                    "int8, 1 worker": {"workers": 1, "precision": "int8"},
                    "int8, 2 workers": {"workers": 2, "precision": "int8"}}
        for name, options in variants.items():  # warm-up: ONNX export and int8 quantisation land in the cache
            extract(ExtractConfig(inputs=tuple(demos), out=root / "warm", weights=str(weights), force=True, quiet=True,
                                  **options))
        print(f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs; "
              f"{args.files} files x {args.frames} frames of 640x480")
        rates: dict[str, list[float]] = {name: [] for name in variants}
        for _ in range(args.rounds):
            for name, options in variants.items():
                start = time.perf_counter()
                extract(ExtractConfig(inputs=tuple(demos), out=root / "out", weights=str(weights), force=True,
                                      quiet=True, **options))
                rates[name].append(args.files * args.frames / (time.perf_counter() - start))
        print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        median = {name: statistics.median(r) for name, r in rates.items()}
        for name, value in median.items():
            print(f"{name:<18} {value:7.1f} frames/s (whole stage: read, decode, infer, write)")
        print(f"2 workers / 1: fp32 {median['fp32, 2 workers'] / median['fp32, 1 worker']:.2f}x, "
              f"int8 {median['int8, 2 workers'] / median['int8, 1 worker']:.2f}x; "
              f"int8 / fp32 (1 worker) {median['int8, 1 worker'] / median['fp32, 1 worker']:.2f}x")


if __name__ == "__main__":
    main()
