"""Online control step latency: condition + gate + predict the next step, 1288-d observation, one core.

Run on demand (do not run it next to other heavy work):
    python -m benchmarks.bench_online [--steps 5000] [--experts 2 4] [--window 10] [--core 0]
    chrt -f 10 python -m benchmarks.bench_online ...   # as a control loop runs: real-time priority (root)

On a shared, loaded machine the wall-clock p99 measures the scheduler (other processes holding the
core), not the step; the "CPU p99" column (the step's own thread CPU time) and a real-time run tell
them apart.

For a CNEP with the pipeline's layout (observes all 1288 columns: features, pose, gripper; predicts
pose + gripper, 8 columns; default widths 128-128) and d experts, times every call of
`OnlineConditioner.step` over `steps` control steps of a synthetic episode (after a warm-up episode)
with torch on one thread and the process pinned to one core, and reports the median and p99.
Baseline in the same run: re-conditioning from scratch each step with `CNEP.generate` on the same
conditioning set (what a conditioner without the running sum would do). The target is p99 < 2 ms.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from cnep.models import CNEPConfig, ColumnRoles, ConditioningPolicy, OnlineConditioner, build_model

TARGET_P99_MS = 2.0  # the control loop's budget per step
WIDTH = 1288
PREDICTED = ((1280, 1288),)  # pose xyz + quaternion + gripper


def episode(steps: int, seed: int = 0) -> np.ndarray:
    """(steps, 1288) float32: |N(0,1)| features, a random walk in the pose, a gripper value."""
    rng = np.random.default_rng(seed)
    data = np.abs(rng.standard_normal((steps, WIDTH), dtype=np.float32))
    data[:, 1280:1287] = np.cumsum(rng.normal(scale=1e-2, size=(steps, 7)), axis=0)
    return data


def time_steps(fn, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wall-clock and thread CPU seconds of `fn(k, row)` for each row, (T,) each."""
    wall, cpu = np.empty(len(rows)), np.empty(len(rows))
    for k, row in enumerate(rows):
        start, start_cpu = time.perf_counter(), time.thread_time()
        fn(k, row)
        wall[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
    return wall, cpu


def bench(n_experts: int, steps: int, window: int) -> dict[str, float]:
    columns = ColumnRoles(width=WIDTH, observed=((0, WIDTH),), predicted=PREDICTED)
    rows = episode(steps)
    model = build_model(CNEPConfig(columns=columns, n_experts=n_experts), [rows], seed=0).eval()
    with torch.no_grad():  # build_model starts the gate uniform; give it trained-like weights
        model.gate.weight.normal_(0, 0.1)
    policy = ConditioningPolicy(window=window, anchors=1)
    online = OnlineConditioner(model, horizon=steps, policy=policy)
    for row in rows[:200]:  # warm-up
        online.step(row)
    online.reset()
    step_s, step_cpu = time_steps(lambda k, row: online.step(row), rows)

    obs_cols = model.obs_columns.numpy()
    times = np.arange(steps) / (steps - 1)

    def from_scratch(k: int, row: np.ndarray) -> None:
        idx = [0] + list(range(max(1, k + 1 - window), k + 1))  # the same set as the policy
        model.generate(times[idx], rows[idx][:, obs_cols], times[[min(k + 1, steps - 1)]])

    base_s, _ = time_steps(from_scratch, rows[: min(steps, 2000)])
    ms = lambda a, q: float(np.percentile(a, q) * 1e3)  # noqa: E731
    return {
        "median": ms(step_s, 50),
        "p99": ms(step_s, 99),
        "cpu_p99": ms(step_cpu, 99),
        "base_median": ms(base_s, 50),
        "base_p99": ms(base_s, 99),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--experts", type=int, nargs="+", default=[2, 4])
    parser.add_argument("--window", type=int, default=10, help="sliding window of the conditioning policy")
    parser.add_argument("--core", type=int, default=0, help="CPU core to pin the process to")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    torch.set_num_threads(1)
    print(
        f"online step, {WIDTH}-d observation, window {args.window} + 1 anchor, {args.steps} steps, 1 thread, "
        f"core {args.core}"
    )
    print(
        f"load average before: {os.getloadavg()[0]:.2f} (wall-clock p99 includes preemption by other processes; "
        "CPU p99 is the step's own thread CPU time)"
    )
    print(
        "| experts | step median ms | step p99 ms | step CPU p99 ms | from-scratch median ms | from-scratch p99 ms "
        "| speed-up (median) | p99 < 2 ms |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for d in args.experts:
        r = bench(d, args.steps, args.window)
        print(
            f"| {d} | {r['median']:.3f} | {r['p99']:.3f} | {r['cpu_p99']:.3f} | {r['base_median']:.3f} | "
            f"{r['base_p99']:.3f} | "
            f"{r['base_median'] / r['median']:.2f}x | {'yes' if r['p99'] < TARGET_P99_MS else 'NO'} |"
        )


if __name__ == "__main__":
    main()
