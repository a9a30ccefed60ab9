"""Recording speed: write/read throughput of 1288-d trajectory files against np.save/np.load.

Run on demand (one core; do not run it next to other heavy work):
    python -m benchmarks.bench_recordings [--steps 20000] [--repeats 5] [--core 0]

Measures in one run, on the same (T, 1288) float32 array (non-negative "features" like MobileNet-v2's
pooled activations, valid pose and gripper columns): `write_trajectory` and `read_trajectory` with
the default chunk compression (lz4) and with zstd, and `np.save`/`np.load` of the array as the
baseline. Each figure is the best of `repeats` timed calls after one warm-up, with the process pinned
to one core. The target is reading at >= 50,000 steps/s on one core.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import timeit
from collections.abc import Callable
from pathlib import Path
from unittest import mock

import numpy as np

import cnep.recordings.writers
from cnep.recordings import Episode, Trajectory, read_trajectory, write_trajectory
from cnep.recordings.constants import KIND_TRAJECTORY, STEP_DIM

READ_TARGET = 50_000  # steps/s on one core: the reading target


def best_seconds(fn: Callable[[], object], repeats: int) -> float:
    """The fastest of `repeats` timed calls after one warm-up call, in seconds."""
    fn()
    return min(timeit.repeat(fn, number=1, repeat=repeats))


def make_trajectory(steps: int, seed: int = 0) -> Trajectory:
    """(steps, 1288) float32: |N(0,1)| features, a random walk in xyz, unit quaternions, gripper."""
    rng = np.random.default_rng(seed)
    data = np.abs(rng.standard_normal((steps, STEP_DIM), dtype=np.float32))  # (T, 1288)
    data[:, 1280:1283] = np.cumsum(rng.normal(scale=1e-3, size=(steps, 3)), axis=0)
    quat = rng.normal(size=(steps, 4))
    data[:, 1283:1287] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    data[:, 1287] = rng.uniform(55, 96, size=steps)
    return Trajectory(
        episode=Episode("bench", fps=30.0),
        timestamps_ns=np.arange(steps, dtype=np.int64) * 33_333_333,
        data=data,
        extractor={"architecture": "mobilenet_v2", "weights": "benchmark"},
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--core", type=int, default=0, help="CPU core to pin the process to")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    traj = make_trajectory(args.steps)
    T = args.steps
    print(
        f"{T} steps x {STEP_DIM} float32 ({traj.data.nbytes / 1e6:.1f} MB), best of {args.repeats}, "
        f"pinned to core {args.core}"
    )

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        npy = d / "traj.npy"
        rows = {}
        rows["np.save / np.load"] = (
            best_seconds(lambda: np.save(npy, traj.data), args.repeats),
            best_seconds(lambda: np.load(npy), args.repeats),
            npy.stat().st_size,
        )
        for compression in ("lz4", "zstd"):
            path = d / f"traj_{compression}.mcap"
            by_kind = {KIND_TRAJECTORY: compression}
            with mock.patch.object(cnep.recordings.writers, "COMPRESSION_BY_KIND", by_kind):  # zstd for comparison only
                write_s = best_seconds(lambda path=path: write_trajectory(path, traj), args.repeats)
            back = read_trajectory(path)
            assert np.array_equal(back.data, traj.data), "round trip changed the data"
            read_s = best_seconds(lambda path=path: read_trajectory(path), args.repeats)
            label = f"cnep MCAP ({compression}{', default' if compression == 'lz4' else ''})"
            rows[label] = (write_s, read_s, path.stat().st_size)

    base_w, base_r, _ = rows["np.save / np.load"]
    print(f"{'':28} {'write steps/s':>14} {'read steps/s':>14} {'size MB':>8} {'write vs np':>11} {'read vs np':>11}")
    for label, (w, r, size) in rows.items():
        print(f"{label:28} {T / w:14,.0f} {T / r:14,.0f} {size / 1e6:8.1f} {base_w / w:10.3f}x {base_r / r:10.3f}x")
    default_read = T / rows["cnep MCAP (lz4, default)"][1]
    verdict = "meets" if default_read >= READ_TARGET else "MISSES"
    print(
        f"read of the default format: {default_read:,.0f} steps/s {verdict} the target of {READ_TARGET:,} steps/s "
        "on one core"
    )


if __name__ == "__main__":
    main()
