"""Two torchrun ranks resumed: the weights of a run killed after a save and resumed, against one run straight through.

    python -m benchmarks.bench_resume_ranks [--steps 20] [--save-every 10] [--kill-in 16]

On the tests' small motion-only set (tests/pipeline/test_train.py), with the two-rank test's settings: one run of
`torchrun --nproc_per_node=2 -m cnep.pipeline train` straight to --steps; another whose ranks are both paused in step
--kill-in (tests/pipeline/fault_driver.py) and killed with SIGKILL, the launcher too, then run again with --resume
from the last save. Prints each run's seconds and whether the two checkpoints' tensors are bit for bit equal.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from safetensors.torch import load_file

from tests.pipeline.test_train import write_set
from tests.pipeline.test_train_distributed import ARGS

ROOT = Path(__file__).resolve().parents[1]
TORCHRUN = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
TRAIN_STEP = "cnep.pipeline.train.stage:StageTrainer.train_step"


def train_args(data: Path, out: Path, steps: int, save_every: int) -> list[str]:
    """`train` with the two-rank test's settings, `steps` steps and a save every `save_every`."""
    settings = dict(zip(ARGS[::2], ARGS[1::2]), **{"--steps": str(steps), "--save-every": str(save_every)})
    return [
        "-q",
        "train",
        str(data),
        "--out",
        str(out),
        "--layout",
        "motion",
        *[x for kv in settings.items() for x in kv],
    ]


def killed_in_step(args: list[str], step: int, go: Path, env: dict) -> None:
    """Run `args` on two ranks until both begin step `step`, then SIGKILL them and their launcher."""
    driver = ["-m", "tests.pipeline.fault_driver", TRAIN_STEP, str(step), str(go), "--"]
    paused = subprocess.Popen(
        [*TORCHRUN, *driver, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    ranks = []
    while len(ranks) < 2:
        line = paused.stdout.readline()
        if not line:
            raise SystemExit(f"the ranks never reached step {step}: {paused.stderr.read()[-3000:]}")
        if line.startswith("paused"):
            ranks.append(int(line.split()[1]))
    for pid in [*ranks, paused.pid]:  # torchrun starts each rank in a session of its own
        os.kill(pid, signal.SIGKILL)
    paused.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--save-every", type=int, default=10)
    parser.add_argument("--kill-in", type=int, default=16, help="the step both ranks are killed in")
    args = parser.parse_args()
    scratch = Path(tempfile.mkdtemp(prefix="bench-resume-"))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    try:
        write_set(scratch / "data")
        straight, resumed = scratch / "straight", scratch / "resumed"
        start = time.perf_counter()
        straight_args = train_args(scratch / "data", straight, args.steps, args.save_every)
        subprocess.run([*TORCHRUN, "-m", "cnep.pipeline", *straight_args], env=env, check=True)
        seconds = {"straight": time.perf_counter() - start}
        resumed_args = train_args(scratch / "data", resumed, args.steps, args.save_every)
        killed_in_step(resumed_args, args.kill_in, scratch / "GO", env)
        seconds["killed"] = time.perf_counter() - start - seconds["straight"]
        time.sleep(1)  # the killed ranks' lock is seen as left by dead processes
        subprocess.run([*TORCHRUN, "-m", "cnep.pipeline", *resumed_args, "--resume"], env=env, check=True)
        seconds["resumed"] = time.perf_counter() - start - seconds["straight"] - seconds["killed"]
        a, b = load_file(straight / "model.safetensors"), load_file(resumed / "model.safetensors")
        equal = a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        print(", ".join(f"{name} {s:.1f} s" for name, s in seconds.items()))
        print(f"{len(a)} tensors, {'bit for bit equal' if equal else 'DIFFERENT'}")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
