"""`cnep extract` across processes: wall time of the stage with --workers 2 against --workers 1, per job size.

Run on demand (say the machine's load when you quote it):
    python -m benchmarks.bench_extract [--jobs 2x24 4x100 4x250] [--precisions fp32 int8] [--rounds 2]

For each job FILESxFRAMES, writes that many demonstration files of 640x480 JPEG frames (smooth random
scenes) into a temporary folder; random weights are calibrated once on the largest job (saved, so
every timed run uses fixed weights and builds no calibration). Then times `pipeline.extract.extract`
with force=True for each precision (int8 on `auto`'s backend) and 1 and 2 workers, round after
round (interleaved, so the ratios share the load), and reports frames/s (median over rounds), the
ratio 2 workers / 1 per job, and the fixed cost of the second worker: the time t = c + frames / r
fitted over the jobs for each variant gives c (start-up) and r (steady frames/s), so 2 workers pay
from frames > (c2 - c1) / (1 / r1 - 1 / r2) on. os.getloadavg() before and after.
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
from cnep.perception import FeatureExtractor
from cnep.pipeline.extract.stage import ExtractConfig, extract
from cnep.recordings import Demonstration, Episode, write_demonstration


def write_demos(folder: Path, files: int, frames: int) -> list[Path]:
    """`files` demonstrations of `frames` JPEG frames each, with a plausible pose and gripper."""
    folder.mkdir(parents=True)
    paths = []
    for k in range(files):
        pose = np.zeros((frames, 7))
        pose[:, 6] = 1.0  # identity quaternion (x, y, z, w)
        pose[:, 0] = np.linspace(0, 0.3, frames)
        demo = Demonstration(
            episode=Episode(episode_id=f"bench-{k}", fps=10.0, task="bench", source="synthetic"),
            timestamps_ns=np.arange(frames, dtype=np.int64) * 100_000_000,
            pose=pose,
            gripper=np.linspace(0, 100, frames),
            frames=jpegs(frames, seed=k),
        )
        paths.append(write_demonstration(folder / f"demo-{k}.mcap", demo))
    return paths


def jpegs(n: int, seed: int, chunk: int = 50) -> list[bytes]:
    """`n` JPEG frames of smooth random 640x480 scenes, made `chunk` at a time (a whole long file would take GBs)."""
    return [
        jpeg
        for start in range(0, n, chunk)
        for jpeg in jpeg_frames(synthetic_frames(min(chunk, n - start), seed=seed * 100_003 + start))
    ]


def parse_job(text: str) -> tuple[int, int]:
    """`FILESxFRAMES` -> (files, frames per file)."""
    files, frames = (int(part) for part in text.lower().split("x"))
    return files, frames


def fit_line(frames: list[int], seconds: list[float]) -> tuple[float, float]:
    """Least-squares t = c + frames / r over the jobs: (c in s, r in frames/s)."""
    slope, intercept = np.polyfit(np.asarray(frames, dtype=float), np.asarray(seconds), 1)
    return float(intercept), float(1 / slope)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", nargs="+", default=["2x24", "4x100", "4x250"], help="FILESxFRAMES per job")
    parser.add_argument("--precisions", nargs="+", default=["fp32", "int8"], choices=("fp32", "int8"))
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    jobs = [parse_job(job) for job in args.jobs]
    with tempfile.TemporaryDirectory(prefix="cnep-bench-extract-") as tmp:
        root = Path(tmp)
        demos = {job: write_demos(root / f"demos-{job[0]}x{job[1]}", *job) for job in jobs}
        weights = root / "weights.pt"
        largest = max(jobs, key=lambda job: job[0] * job[1])
        extract(
            ExtractConfig(
                inputs=tuple(demos[largest]),
                out=root / "calibrate",
                weights="random",
                save_weights=weights,
                quiet=True,
                views=0,
            )
        )
        variants = {  # the network's throughput: each frame once, without views (perception.views)
            (precision, workers): {"precision": precision, "workers": workers, "views": 0}
            for precision in args.precisions
            for workers in (1, 2)
        }
        backends = {
            precision: FeatureExtractor(str(weights), precision=precision).identity["backend"]
            for precision in args.precisions
        }
        for job in jobs:  # warm-up: ONNX export and int8 quantisation (one per job's frames) land in the cache
            for options in variants.values():
                extract(
                    ExtractConfig(
                        inputs=tuple(demos[job]),
                        out=root / "warm",
                        weights=str(weights),
                        force=True,
                        quiet=True,
                        **options,
                    )
                )
        print(
            f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} CPUs; jobs "
            f"{', '.join(args.jobs)} (files x frames of 640x480); backends {backends}"
        )
        seconds: dict[tuple, list[float]] = {}
        for _ in range(args.rounds):
            for job in jobs:
                for key, options in variants.items():
                    start = time.perf_counter()
                    extract(
                        ExtractConfig(
                            inputs=tuple(demos[job]),
                            out=root / "out",
                            weights=str(weights),
                            force=True,
                            quiet=True,
                            **options,
                        )
                    )
                    seconds.setdefault((job, *key), []).append(time.perf_counter() - start)
        print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        median = {key: statistics.median(values) for key, values in seconds.items()}
        print(
            f"{'job':>9} {'frames':>6}  "
            + "  ".join(f"{p} {w}w fr/s" for p, w in variants)
            + "  "
            + "  ".join(f"{p} 2w/1w" for p in args.precisions)
        )
        for job in jobs:
            n = job[0] * job[1]
            rates = [n / median[(job, *key)] for key in variants]
            ratios = [median[(job, p, 1)] / median[(job, p, 2)] for p in args.precisions]
            print(
                f"{job[0]:>4}x{job[1]:<4} {n:>6}  "
                + "  ".join(f"{r:13.1f}" for r in rates)
                + "  "
                + "  ".join(f"{r:10.2f}x" for r in ratios)
            )
        if len(jobs) >= 2:
            frames = [job[0] * job[1] for job in jobs]
            for precision in args.precisions:
                (c1, r1), (c2, r2) = (fit_line(frames, [median[(job, precision, w)] for job in jobs]) for w in (1, 2))
                even = (c2 - c1) / (1 / r1 - 1 / r2) if r2 > r1 else float("inf")
                print(
                    f"{precision}: 1 worker {c1:.1f} s + frames / {r1:.1f}; 2 workers {c2:.1f} s + frames / {r2:.1f}; "
                    f"2 workers pay from ~{even:.0f} frames"
                )
        if set(args.precisions) == {"fp32", "int8"}:
            print(
                f"int8 / fp32 with 1 worker, largest job: "
                f"{median[(largest, 'fp32', 1)] / median[(largest, 'int8', 1)]:.2f}x"
            )


if __name__ == "__main__":
    main()
