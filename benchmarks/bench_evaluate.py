"""Where the time of `cnep evaluate` goes: its plan, each network's training rate, the baselines and the scoring.

Run on demand (one torch thread, as the evaluation's workers train; say the machine's load when you quote it):
    python -m benchmarks.bench_evaluate [--table all] [--seeds 3] [--steps 200]

For the plan of `cnep evaluate --table T --seeds N` (pipeline.evaluate.stage.plan, every network once):
- per (set, network shape): how many networks, their planned steps, and one of them trained for
  `--steps` steps (after 20 unmeasured) on seed 0: steps/s, and the seconds to score it on every protocol;
- per set: the seconds of one baselines job (fit and score ProMP, GMM-GMR with and without ridge, nearest demo);
- the plan's core-seconds at those rates (planned steps / steps/s + scoring + baselines), and that divided by
  the default worker count: the run's wall time on an idle machine if the workers never wait, without early stops.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict

import torch

from cnep.models import TrainConfig
from cnep.models.train import prepare_fit
from cnep.pipeline.evaluate.constants import JOBS, PAPER_NLL_BETA, TABLES
from cnep.pipeline.evaluate.jobs import Job, _scored_network, model_config, queries, run_job
from cnep.pipeline.evaluate.stage import EvaluateConfig, plan

WARMUP_STEPS = 20


def network_rate(job: Job, steps: int) -> tuple[float, float]:
    """(training steps/s, seconds to score) of `job`'s network on its set, seed 0."""
    s, qs = queries(job.set_name, 0, job.n_queries)
    config = model_config(job.spec, job.cnmp_matches)
    trainer, _ = prepare_fit(
        list(s.train), config, TrainConfig(steps=job.steps, seed=0, nll_beta=PAPER_NLL_BETA), list(s.val)
    )
    for _ in range(WARMUP_STEPS):
        trainer.train_step()
    start = time.perf_counter()
    for _ in range(steps):
        trainer.train_step()
    rate = steps / (time.perf_counter() - start)
    trainer.model.eval()
    history = [{"step": trainer.step, "val_error": 0.0, "usage": [1.0]}]  # what scoring reads of a real history
    start = time.perf_counter()
    _scored_network(job, s, qs, config, trainer.model, history, 0.0, trainer.step)
    return rate, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--table", choices=(*TABLES, "all"), default="all")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=200, help="measured steps per network shape")
    args = parser.parse_args()
    torch.set_num_threads(1)
    load = os.getloadavg()
    jobs = plan(EvaluateConfig(tables=TABLES if args.table == "all" else (args.table,), seeds=args.seeds))
    shapes: dict[tuple, list[Job]] = defaultdict(list)
    for job in jobs:
        if job.spec is not None:
            shapes[(job.set_name, job.spec.n_experts)].append(job)
    total = 0.0
    print(
        f"{len(jobs)} fits, {sum(len(v) for v in shapes.values())} networks, "
        f"{sum(j.steps for v in shapes.values() for j in v)} training steps"
    )
    print("| set | network | networks | steps each | steps/s | score s | core-s |\n|---|---|---|---|---|---|---|")
    for (set_name, d), group in sorted(shapes.items()):
        rate, score_s = network_rate(group[0], args.steps)
        seconds = sum(j.steps / rate + score_s for j in group)
        total += seconds
        name = "CNMP" if d == 1 else f"CNEP d={d}"
        print(
            f"| {set_name} | {name} | {len(group)} | {group[0].steps} | {rate:.1f} | {score_s:.2f} | {seconds:.0f} |",
            flush=True,
        )
    for set_name in dict.fromkeys(j.set_name for j in jobs):
        start = time.perf_counter()
        run_job(Job(set_name, 0, None, 0, jobs[0].n_queries))
        seconds = time.perf_counter() - start
        runs = sum(j.spec is None and j.set_name == set_name for j in jobs)
        total += runs * seconds
        print(f"| {set_name} | baselines job | {runs} | | | {seconds:.1f} | {runs * seconds:.0f} |", flush=True)
    print(f"\ntotal {total:.0f} core-s; / {JOBS} workers = {total / JOBS / 60:.1f} min without early stops")
    print(f"load average before {load[0]:.2f}, after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
