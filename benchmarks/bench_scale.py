"""`cnep train` on thousands of files: peak memory, two ranks against one, time to the first step; the up-to-date check.

Run on demand, one at a time on a shared machine (it writes FILES x 100 x 1288 float32 trajectories, 0.5 MB each):
    python -m benchmarks.bench_scale --files 2000 [--data DIR] [--before CHECKOUT] [--two-ranks] [--keep]

Writes FILES synthetic 1288-wide trajectory files of STEPS steps (the project's own writer; into DIR, reused if it
already holds them, else a temporary folder removed at the end), then:
- imports: the peak RSS of a process that imports torch and the train stage and does nothing else;
- one process: `cnep -v train DIR --layout scene --steps N` in a subprocess, its RSS sampled every 20 ms from
  /proc (psutil): the peak, and the seconds from its start to the log line that training starts (the data read, the
  normaliser fitted, the trainer made);
- with --two-ranks: the same under `torchrun --standalone --nproc_per_node=2`, the peak of the two ranks' RSS summed
  (the launcher left out) and each rank's peak PSS (shared pages divided among the processes mapping them);
- with --before CHECKOUT (a checkout of another version of this repository): its one-process run, for the ratios;
- the extract stage's up-to-date check (`up_to_date_steps`) over every file as a finished output.
Prints each target (issue: peak RSS at most 1.5x the raw training columns plus the imports; two ranks at most 1.2x
one; the first step in at most a third of the time of --before; the up-to-date check under 2 s) as met, or by how
much it is missed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import psutil

from cnep.recordings import Episode, Trajectory, write_trajectory

WIDTH = 1288
EXTRACTOR = {
    "architecture": "mobilenet_v2",
    "feature_width": "1280",
    "weights": "random",
    "weights_sha256": "0" * 64,
    "preprocessing": "bench",
    "backend": "onnxruntime",
}
STARTED = re.compile(r"training on \d+ demonstrations")
MIB = 1 << 20


def write_files(folder: Path, files: int, steps: int) -> list[Path]:
    """`files` trajectory files of `steps` seeded random features, a slow pose and a gripper (skipped if present)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"episode-{k:05d}.mcap" for k in range(files)]
    for k, path in enumerate(paths):
        if path.is_file():
            continue
        rng = np.random.default_rng(k)
        data = rng.standard_normal((steps, WIDTH)).astype(np.float32)  # (T, 1288)
        data[:, 1280:1283] = np.linspace(0, 0.3, steps)[:, None] + 0.01 * rng.standard_normal((steps, 3))
        data[:, 1283:1287] = (0.0, 0.0, 0.0, 1.0)
        data[:, 1287] = np.linspace(0, 100, steps)
        episode = Episode(episode_id=f"bench-{k}", fps=10.0, task="bench", source="synthetic")
        timestamps = np.arange(steps, dtype=np.int64) * 100_000_000
        write_trajectory(path, Trajectory(episode=episode, timestamps_ns=timestamps, data=data, extractor=EXTRACTOR))
    return paths


class Sampler:
    """Samples the RSS (and PSS) of a process and its descendants every `period` s while it runs."""

    def __init__(self, process: subprocess.Popen, period: float = 0.02, skip_root: bool = False) -> None:
        self.root, self.period, self.skip_root = psutil.Process(process.pid), period, skip_root
        self.peak_total, self.peak_pss = 0, {}
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while self.root.is_running() and self.root.status() != psutil.STATUS_ZOMBIE:
            total = 0
            try:
                procs = self.root.children(recursive=True) + ([] if self.skip_root else [self.root])
            except psutil.NoSuchProcess:
                break
            for proc in procs:
                try:
                    total += proc.memory_info().rss
                    if self.skip_root:  # PSS reads smaps: only for the ranks, which are few
                        pss = proc.memory_full_info().pss
                        self.peak_pss[proc.pid] = max(self.peak_pss.get(proc.pid, 0), pss)
                except psutil.Error:
                    continue
            self.peak_total = max(self.peak_total, total)
            time.sleep(self.period)


def timed_run(command: list[str], env: dict, skip_root: bool = False) -> SimpleNamespace:
    """Run `command`; its peak RSS (bytes, summed over its processes), ranks' peak PSS, seconds to the first step."""
    start = time.perf_counter()
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    sampler = Sampler(process, skip_root=skip_root)
    first_step, lines = None, []
    for line in process.stdout:
        lines.append(line)
        if first_step is None and STARTED.search(line):
            first_step = time.perf_counter() - start
    status = process.wait()
    sampler.thread.join()
    if status != 0:
        raise SystemExit(f"{' '.join(command)} failed ({status}):\n{''.join(lines[-30:])}")
    return SimpleNamespace(
        peak=sampler.peak_total,
        pss=sorted(sampler.peak_pss.values()),
        first_step=first_step,
        wall=time.perf_counter() - start,
    )


def checkout_path(checkout: Path, scratch: Path) -> str:
    """A folder whose `cnep` package is the checkout's (its library folders, those at its root with an __init__.py,
    linked), for PYTHONPATH."""
    package = scratch / "before" / "cnep"
    package.mkdir(parents=True)
    for init in checkout.resolve().glob("*/__init__.py"):
        if init.parent.name not in ("tests", "benchmarks", "examples"):
            (package / init.parent.name).symlink_to(init.parent)
    return str(package.parent)


def train_command(data: Path, out: Path, steps: int, ranks: int = 1) -> list[str]:
    launcher = ["-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}"] if ranks > 1 else []
    return [
        sys.executable,
        *launcher,
        "-m",
        "cnep.pipeline",
        "-v",
        "train",
        str(data),
        "--out",
        str(out),
        "--layout",
        "scene",
        "--steps",
        str(steps),
        "--val-every",
        str(max(1, steps // 2)),
        "--save-every",
        str(steps),
    ]


def imports_peak(env: dict) -> int:
    """Peak RSS (bytes) of a process that only imports torch and the train stage."""
    code = "import torch, cnep.pipeline.train.stage, time; time.sleep(0.5)"
    return timed_run([sys.executable, "-c", code], env).peak


def check_up_to_date(paths: list[Path], scratch: Path) -> tuple[float, int]:
    """Seconds for the extract stage's up-to-date check over `paths` as finished outputs of older sources."""
    from cnep.pipeline.extract.stage import up_to_date_steps

    source = scratch / "source.mcap"
    source.write_bytes(b"")
    os.utime(source, (0, 0))  # older than every output
    extractor = SimpleNamespace(identity=EXTRACTOR)
    start = time.perf_counter()
    current = [up_to_date_steps(source, path, lambda: extractor) for path in paths]
    return time.perf_counter() - start, sum(n is not None for n in current)


def verdict(name: str, value: float, limit: float, unit: str = "") -> str:
    met = value <= limit
    gap = "" if met else f", {value / limit:.2f}x the limit"
    return f"{'MET ' if met else 'MISSED'} {name}: {value:.3g}{unit} against at most {limit:.3g}{unit}{gap}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=2000)
    parser.add_argument("--steps-per-file", type=int, default=100)
    parser.add_argument("--train-steps", type=int, default=200, help="training steps of each run")
    parser.add_argument("--data", type=Path, help="folder of the trajectory files (written if missing, kept)")
    parser.add_argument("--before", type=Path, help="a checkout of another version, run for the ratios")
    parser.add_argument("--two-ranks", action="store_true", help="also train under torchrun with two processes")
    args = parser.parse_args()

    scratch = Path(tempfile.mkdtemp(prefix="bench-scale-"))
    data = args.data or scratch / "data"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    try:
        start = time.perf_counter()
        paths = write_files(data, args.files, args.steps_per_file)
        raw = args.files * args.steps_per_file * WIDTH * 4  # the training columns, float32 (scene: all of them)
        written = time.perf_counter() - start
        print(f"{args.files} files, {raw / MIB:.0f} MiB of float32 columns (written in {written:.0f} s)")
        imports = imports_peak(env)
        print(f"imports: peak RSS {imports / MIB:.0f} MiB")
        one = timed_run(train_command(data, scratch / "one", args.train_steps), env)
        print(
            f"one process: peak RSS {one.peak / MIB:.0f} MiB ({(one.peak - imports) / MIB:.0f} above the imports), "
            f"first step at {one.first_step:.1f} s, {one.wall:.0f} s in all"
        )
        targets = [verdict("peak RSS / (1.5 x raw + imports)", one.peak / (1.5 * raw + imports), 1.0)]
        if args.two_ranks:
            two = timed_run(train_command(data, scratch / "two", args.train_steps, ranks=2), env, skip_root=True)
            pss = ", ".join(f"{p / MIB:.0f}" for p in two.pss)
            print(
                f"two ranks: peak RSS {two.peak / MIB:.0f} MiB summed (PSS {pss} MiB), "
                f"first step at {two.first_step:.1f} s"
            )
            targets.append(verdict("two ranks' RSS / one's", two.peak / one.peak, 1.2))
        if args.before is not None:
            before_env = {**env, "PYTHONPATH": checkout_path(args.before, scratch)}
            before = timed_run(train_command(data, scratch / "before-out", args.train_steps), before_env)
            print(
                f"before ({args.before}): peak RSS {before.peak / MIB:.0f} MiB, first step at {before.first_step:.1f} s"
            )
            targets.append(verdict("first step / before's", one.first_step / before.first_step, 1 / 3))
        seconds, current = check_up_to_date(paths, scratch)
        print(f"up-to-date check: {current} of {len(paths)} outputs current in {seconds:.2f} s")
        targets.append(verdict("up-to-date check", seconds, 2.0, " s"))
        print("\n".join(targets))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
