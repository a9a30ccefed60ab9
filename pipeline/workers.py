"""The pipeline's thread policy, in one place, and worker processes for CPU-bound jobs.

Measured on the shared 2-core machine (benchmarks/bench_threads.py, docs/perception.md): a small
network on two threads next to another busy process runs up to 10x slower than on one, because
each of its many tiny kernels waits for a thread that is not scheduled. So:

- small-model work (training, the online step, replay, the evaluation's fits) runs SMALL_MODEL_THREADS
  (one) intra-op thread per process and scales across processes (`single_thread_processes`, torchrun);
- the feature extractor (a real CNN, large kernels) takes its share of the cores, `cores // workers`,
  in an ONNX Runtime session whose idle threads sleep instead of spinning (perception.backends), so two
  extractors, or an extractor beside a trainer, do not starve each other;
- an explicit thread count (`cnep extract --threads N`) always wins.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
SMALL_MODEL_THREADS = 1  # intra-op threads of a process that trains or runs a CNEP


def cpu_cores() -> int:
    """CPU cores this process may run on (its affinity mask, not the machine's count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def inference_threads(requested: int | None = None, workers: int = 1) -> int:
    """Intra-op threads of one feature-extraction process: `requested` if given, else its share of the cores."""
    if requested is not None:
        return requested
    return max(1, cpu_cores() // max(1, workers))


@contextmanager
def torch_threads(threads: int = SMALL_MODEL_THREADS) -> Iterator[None]:
    """Run the block with `threads` torch intra-op threads, restoring the previous count after it."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextmanager
def single_thread_processes(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` spawned processes whose BLAS and torch start with one thread each."""
    with thread_environment(1):
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            yield pool


@contextmanager
def thread_environment(threads: int) -> Iterator[None]:
    """Set the BLAS/OpenMP thread variables (read by spawned processes' libraries at import), then restore them."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update({name: str(threads) for name in THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
