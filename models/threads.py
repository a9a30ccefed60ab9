"""How many threads torch runs a small network on: one per process, the fastest on a busy machine.

A small network on two threads next to another busy process runs many times slower than on one, because
each of its many tiny kernels waits for a thread that is not scheduled (benchmarks/bench_threads.py).
More cores are used by more processes (pipeline.workers), not by more threads.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

SMALL_MODEL_THREADS = 1  # torch intra-op threads of a process that trains or runs a CNEP


@contextmanager
def torch_threads(threads: int | None = SMALL_MODEL_THREADS) -> Iterator[None]:
    """Run the block with `threads` torch intra-op threads (None: leave the count alone), then restore it."""
    import torch  # here: importing this module (through models.config) must not load torch

    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
