"""Worker processes for CPU-bound jobs: spawned, each with one BLAS and one torch thread.

Small networks train fastest on one thread each (the demo's CNEP, both cores busy: 53 ms per step on
one thread, 216 ms on two), so independent fits run side by side in processes, not sharing threads.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def single_thread_processes(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` spawned processes whose BLAS and torch start with one thread each."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update({name: "1" for name in THREAD_VARIABLES})  # read by the workers' libraries at import
    try:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            yield pool
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
