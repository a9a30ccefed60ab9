"""Batched training with and without the small-model workers' malloc settings (pipeline.workers.SMALL_MODEL_MALLOC).

Run on demand:
    python -m benchmarks.bench_allocator [--experts 2] [--k 4] [--steps 30] [--rounds 2]

Each round starts two fresh processes one after the other, one with glibc's default malloc and one with
SMALL_MODEL_MALLOC in its environment (glibc reads them at start). Each measures, with one torch thread,
k models one after another and the same k as one `models.batched.BatchedTrainer`: model-steps per
second of process CPU time (steadier than wall time on a shared machine) and minor page faults per step.
Reported: each process's numbers and the batched / sequential ratio under each setting.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

from cnep.pipeline.workers import SMALL_MODEL_MALLOC


def measure(n_experts: int, k: int, steps: int) -> dict[str, float]:
    """In this process: CPU-time model-steps/s and minor faults per step of k sequential and k batched models."""
    import torch

    from benchmarks.bench_training import trainers
    from cnep.models.batched import BatchedTrainer

    torch.set_num_threads(1)
    sequential, batched = trainers(n_experts, k), BatchedTrainer(trainers(n_experts, k))
    out = {}
    for name, step in (("sequential", lambda: [t.train_step() for t in sequential]), ("batched", batched.train_step)):
        for _ in range(3):  # warm-up
            step()
        faults, start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.process_time()
        for _ in range(steps):
            step()
        out[name] = k * steps / (time.process_time() - start)
        out[name + "_faults"] = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / steps
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experts", type=int, default=2)
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.experts, args.k, args.steps)))
        return
    print(f"load before: {os.getloadavg()[0]:.2f}; d = {args.experts}, k = {args.k}")
    base = {name: value for name, value in os.environ.items() if name not in SMALL_MODEL_MALLOC}
    for _ in range(args.rounds):
        for label, env in (("glibc default", base), ("SMALL_MODEL_MALLOC", {**base, **SMALL_MODEL_MALLOC})):
            command = [
                sys.executable,
                "-m",
                "benchmarks.bench_allocator",
                "--child",
                "--experts",
                str(args.experts),
                "--k",
                str(args.k),
                "--steps",
                str(args.steps),
            ]
            r = json.loads(
                subprocess.run(
                    command, env={**env, "OMP_NUM_THREADS": "1"}, check=True, capture_output=True, text=True
                ).stdout.splitlines()[-1]
            )
            print(
                f"{label:>18}: model-steps per CPU-s sequential {r['sequential']:.1f}, batched {r['batched']:.1f} "
                f"({r['batched'] / r['sequential']:.2f}x); minor faults a step {r['sequential_faults']:.0f} / "
                f"{r['batched_faults']:.0f}"
            )
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
