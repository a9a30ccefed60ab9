"""The pipeline's thread policy, in one place, and worker processes for CPU-bound jobs.

A small network runs fastest on one thread of a busy machine (models.threads says why). So:

- small-model work (training, the online step, replay, the evaluation's fits) runs
  models.threads.SMALL_MODEL_THREADS (one) intra-op thread per process (`models.threads.torch_threads`)
  and scales across processes (`single_thread_processes`, torchrun);
- the feature extractor (a real CNN, large kernels) takes its share of the cores, `cores // workers`,
  in an ONNX Runtime session whose idle threads sleep instead of spinning (perception.backends), so two
  extractors, or an extractor beside a trainer, do not starve each other;
- an explicit thread count (`cnep extract --threads N`) always wins.

Ctrl-C belongs to the command's own process (pipeline.contract): a terminal sends SIGINT to every process of its
group, so the processes started here (a pool's workers, `report_manager`'s server) start with it ignored and are
stopped by the process that started them; where that process is killed outright, they end by themselves.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing.context import SpawnContext, SpawnProcess
from multiprocessing.managers import SyncManager

from cnep.pipeline.contract import deferred_interrupts, interruption

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
# glibc's malloc settings for small-model worker processes (read at their start; other allocators ignore
# them). By default glibc gives blocks above its mmap threshold back to the kernel when they are freed, so
# a batched training step (models.batched: k models' activations, megabytes a step) faults fresh pages in
# every step; with these thresholds they stay mapped, the faults all but vanish and batching pays more
# (`python -m benchmarks.bench_allocator` measures both). One model alone faults a few pages a step either way.
SMALL_MODEL_MALLOC = {"MALLOC_MMAP_THRESHOLD_": str(256 << 20), "MALLOC_TRIM_THRESHOLD_": str(512 << 20)}
PARENT_CHECK_S = 1.0  # how often a worker checks that the process that started it is still there
ORPHANED_EXIT = 70  # a worker's exit status when it ends because that process is gone (sysexits' EX_SOFTWARE)


def cpu_cores() -> int:
    """CPU cores this process may run on (its affinity mask, not the machine's count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def inference_threads(requested: int | None = None, workers: int = 1) -> int:
    """Intra-op threads of one feature-extraction process: `requested` if given, else its share of the cores."""
    if requested is not None:
        return requested
    return max(1, cpu_cores() // max(1, workers))


@contextmanager
def single_thread_processes(workers: int, wait: bool = True) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` spawned processes whose BLAS and torch start with one thread each, with
    SMALL_MODEL_MALLOC's allocator settings (`process_pool`: stopped when the block fails)."""
    with (
        environment({**dict.fromkeys(THREAD_VARIABLES, "1"), **SMALL_MODEL_MALLOC}),
        process_pool(workers, wait=wait) as pool,
    ):
        yield pool


@contextmanager
def process_pool(
    workers: int, initializer=None, initargs: tuple = (), wait: bool = True
) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` spawned processes. When the block fails or is interrupted (Ctrl-C, SIGTERM), the jobs
    not started are dropped and the workers are stopped and waited for, instead of every queued job running
    first; a worker stopped while writing leaves only a temporary file, which the output's next run removes.
    With `wait` False a block that ends normally does not wait for the idle workers to exit (a worker that has
    loaded torch takes seconds to): they exit beside what comes next."""
    pool = ProcessPoolExecutor(
        workers, mp_context=_DEAF_SPAWN, initializer=_worker_start, initargs=(initializer, initargs)
    )
    try:
        yield pool
    except BaseException:
        processes = list((pool._processes or {}).values())  # no public way to stop the workers before Python 3.14
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join()
        raise
    pool.shutdown(wait=wait)


class _DeafProcess(SpawnProcess):
    """A spawned process that starts deaf to Ctrl-C (`_children_deaf`) and ends when the process that started it is
    gone (`_ends_with_parent`)."""

    def start(self) -> None:
        with _children_deaf():
            super().start()

    def run(self) -> None:
        _ends_with_parent()
        super().run()


class _DeafSpawn(SpawnContext):
    """The spawn context whose processes start deaf to Ctrl-C: the pools' and `report_manager`'s."""

    Process = _DeafProcess


_DEAF_SPAWN = _DeafSpawn()


@contextmanager
def report_manager() -> Iterator[SyncManager]:
    """A spawned multiprocessing Manager for the block (its `Queue()`s carry workers' reports: pipeline.progress),
    deaf to Ctrl-C, shut down when the block ends. SIGINT and SIGTERM wait while it starts (a second one does not):
    a server whose start is given up writes its address to no one, with a traceback."""
    manager = SyncManager(ctx=_DEAF_SPAWN)
    with deferred_interrupts() as received:
        manager.start()
    with manager:
        if received() is not None:
            raise interruption(received())
        yield manager


@contextmanager
def _children_deaf() -> Iterator[None]:
    """Processes started in the block ignore SIGINT from their first instruction (an ignored signal stays ignored
    across exec, and Python then installs no KeyboardInterrupt of its own): a terminal's Ctrl-C, which reaches the
    whole process group, leaves them to the process that started them instead of interrupting their start-up with a
    traceback. A code block of theirs may still take the signal (`contract.deferred_interrupts`). This process
    ignores SIGINT for the block too (keep it to the start of a process, milliseconds: a Ctrl-C then is lost);
    outside the main thread, where signals cannot be set, or under a handler not set from Python, nothing changes."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _ends_with_parent() -> None:
    """End this process (exit ORPHANED_EXIT) within PARENT_CHECK_S of the process that started it ending. A parent that
    is killed outright (SIGKILL, the out-of-memory killer) stops no one: its workers would go on with their jobs for
    minutes, writing into folders a rerun of the command is writing too. Orphaned, a process gets a new parent
    (init, or a subreaper), which a daemon thread of it notices."""
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(PARENT_CHECK_S)
            if os.getppid() != parent:
                os._exit(ORPHANED_EXIT)

    threading.Thread(target=watch, name="ends-with-parent", daemon=True).start()


def _worker_start(initializer, initargs: tuple) -> None:
    """What a pool's worker runs first: tqdm's lock made for this process alone, then `initializer(*initargs)`.

    tqdm's own lock is a semaphore that processes share; a worker stopped with a failed run never frees one it made,
    and the multiprocessing resource tracker would say so in a warning after the run's error line. The workers'
    bars are drawn by the process that started them (`pipeline.progress`), so they need no lock between processes.
    """
    import threading

    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())
    if initializer is not None:
        initializer(*initargs)


def thread_environment(threads: int):
    """Set the BLAS/OpenMP thread variables (read by spawned processes' libraries at import), then restore them."""
    return environment({name: str(threads) for name in THREAD_VARIABLES})


@contextmanager
def environment(values: dict[str, str]) -> Iterator[None]:
    """Set environment variables for the block (spawned processes inherit them), then restore them."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
