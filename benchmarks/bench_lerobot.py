"""Time to bring a LeRobot dataset in: `cnep ingest` then `cnep extract`, as a user runs them (subprocesses).

Run on demand:
    python -m benchmarks.bench_lerobot [--episodes 50] [--steps 30] [--size 96] [--version v3.0] [--threads 1]

Builds a synthetic dataset with the test fixture builder (tests/recordings/lerobot_sources.py: H.264
video, one camera, an 8-value state vector), then runs `python -m cnep.pipeline ingest` and
`python -m cnep.pipeline extract` (random weights, calibrated on the frames; ImageNet weights give the same
network cost) with stderr redirected to a file, the way a CI log sees it. Reports wall seconds per stage,
frames per second, and the number of lines the extract stage wrote to that log.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.recordings.lerobot_sources import build_lerobot


def timed(command: list[str], log: Path, env: dict[str, str]) -> float:
    """Run `command` with stderr to `log`; wall seconds."""
    start = time.perf_counter()
    with open(log, "w") as err:
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=err, env=env)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--steps", type=int, default=30, help="frames per episode")
    parser.add_argument("--size", type=int, default=96, help="frame width and height in pixels")
    parser.add_argument("--version", default="v3.0", choices=("v2.1", "v3.0"))
    parser.add_argument("--threads", type=int, default=1, help="inference threads of the extract stage")
    parser.add_argument("--keep", type=Path, default=None, help="keep the work folder here (default: a temporary one)")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_lerobot_"))
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads), "MKL_NUM_THREADS": str(args.threads)}
    start = time.perf_counter()
    build_lerobot(work / "dataset", args.version, episodes=args.episodes, steps=args.steps, size=args.size)
    built = time.perf_counter() - start
    frames = args.episodes * args.steps
    python = [sys.executable, "-m", "cnep.pipeline"]
    ingest_s = timed([*python, "ingest", str(work / "dataset"), "--out", str(work / "demos")], work / "ingest.log", env)
    extract_s = timed(
        [
            *python,
            "extract",
            str(work / "demos"),
            "--out",
            str(work / "traj"),
            "--weights",
            "random",
            "--backend",
            "eager",
            "--threads",
            str(args.threads),
        ],
        work / "extract.log",
        env,
    )
    lines = (work / "extract.log").read_text().splitlines()
    print(
        f"dataset: LeRobot {args.version}, {args.episodes} episodes x {args.steps} frames of {args.size}x{args.size} "
        f"px (H.264), built in {built:.1f} s"
    )
    print(f"ingest : {ingest_s:6.1f} s  ({frames / ingest_s:6.1f} frames/s, process start-up included)")
    print(
        f"extract: {extract_s:6.1f} s  ({frames / extract_s:6.1f} frames/s, {args.threads} thread(s), incl. "
        f"calibration and start-up)"
    )
    print(
        f"extract log (stderr not a terminal): {len(lines)} lines, "
        f"{sum(line.count(chr(13)) for line in lines)} carriage "
        f"returns; last: {lines[-1] if lines else ''}"
    )
    print(f"load average: {os.getloadavg()[0]:.2f}; work folder: {work}")


if __name__ == "__main__":
    main()
