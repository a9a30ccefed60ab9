"""Training throughput: steps/s of one CNEP (fused vs per-tensor Adam) and of k models batched vs one after another.

Run on demand (one torch thread, as the pipeline trains; say the machine's load when you quote it):
    python -m benchmarks.bench_training [--experts 2 4] [--k 4] [--steps 30] [--rounds 3] [--device cuda]

For each number of experts d (the paper's loss, CNEPConfig defaults otherwise: widths 128, batch 32, the 4-mode set):
- `foreach`: one `models.Trainer` step with Adam(foreach=True), the optimiser the fused one is measured against;
- `fused`:   the same with the Trainer's fused Adam (the default);
- `sequential`: k Trainers (seeds 0..k-1) stepped one after another, model-steps/s;
- `batched`:  the same k runs in one `models.batched.BatchedTrainer`, model-steps/s.
The variants are interleaved round by round, so each ratio is measured under the same load; the
medians over rounds are reported, with os.getloadavg() before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from cnep.models import CNEPConfig, TrainConfig
from cnep.models.batched import BatchedTrainer
from cnep.models.synthetic import make_set
from cnep.models.train import Trainer, prepare_fit

SYNTHETIC_SET = "multimodal"


def trainers(n_experts: int, k: int, device: str = "cpu") -> list[Trainer]:
    """k fresh Trainers of the default CNEP with `n_experts`, seeds 0..k-1, each on its seed's data, on `device`."""
    out = []
    for seed in range(k):
        data = make_set(SYNTHETIC_SET, seed)
        trainer, _ = prepare_fit(
            list(data.train),
            CNEPConfig(n_experts=n_experts, assignment="paper"),
            TrainConfig(seed=seed),
            list(data.val),
        )
        trainer.model.to(device)  # in place: the optimiser keeps its parameters; batches follow them (Trainer.device)
        out.append(trainer)
    return out


def with_foreach_adam(trainer: Trainer) -> Trainer:
    """The Trainer with the per-tensor (foreach) Adam it used before the fused one, same groups and settings."""
    groups = [{**{k: v for k, v in g.items() if k not in ("fused", "foreach")}} for g in trainer.optimizer.param_groups]
    trainer.optimizer = torch.optim.Adam(groups, lr=trainer.cfg.lr, foreach=True)
    return trainer


def seconds(step, n: int, device: str = "cpu") -> float:
    """Wall time of `n` calls of `step`, the GPU's queue drained at both ends."""
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    sync()
    start = time.perf_counter()
    for _ in range(n):
        step()
    sync()
    return time.perf_counter() - start


def bench(n_experts: int, k: int, steps: int, rounds: int, device: str = "cpu") -> dict[str, float]:
    """Median model-steps/s of each variant over `rounds` interleaved rounds of `steps` steps."""
    foreach, fused = with_foreach_adam(trainers(n_experts, 1, device)[0]), trainers(n_experts, 1, device)[0]
    sequential, batched = trainers(n_experts, k, device), BatchedTrainer(trainers(n_experts, k, device))
    variants = {
        "foreach": (lambda: foreach.train_step(), 1),
        "fused": (lambda: fused.train_step(), 1),
        "sequential": (lambda: [t.train_step() for t in sequential], k),
        "batched": (lambda: batched.train_step(), k),
    }
    for step, _ in variants.values():  # warm-up: allocator, first-call costs
        seconds(step, 3, device)
    rates: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        for name, (step, models) in variants.items():
            rates[name].append(models * steps / seconds(step, steps, device))
    return {name: statistics.median(r) for name, r in rates.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experts", type=int, nargs="+", default=[2, 4])
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(
        f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; one torch thread; k = {args.k}; "
        f"device {args.device}"
    )
    for d in args.experts:
        r = bench(d, args.k, args.steps, args.rounds, args.device)
        print(
            f"d={d}: steps/s foreach Adam {r['foreach']:.1f}, fused Adam {r['fused']:.1f} "
            f"({r['fused'] / r['foreach']:.2f}x); model-steps/s {args.k} sequential {r['sequential']:.1f}, "
            f"{args.k} batched {r['batched']:.1f} ({r['batched'] / r['sequential']:.2f}x)"
        )
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
