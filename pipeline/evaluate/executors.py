"""Where `cnep evaluate` runs its units of work besides this machine's process pool: a Dask or Ray cluster.

    for unit, results in run_on_cluster(run_unit, units, "dask", "tcp://scheduler:8786", workers=2): ...

A unit is self-contained and `work(unit)` (a function importable on the workers) runs it; both commands' units come
through pipeline.evaluate.pool. `cnep evaluate`'s (`pipeline.evaluate.jobs.run_unit`) names the set, the seed and the
model, and builds its data, seeds and threads itself; `cnep sim grid`'s (`pipeline.sim.grid_unit.run_grid_unit`) names
its folders, which every worker reaches on a shared file system. So any engine that can call a Python function on
another machine runs it and returns the same numbers as the local pool. The engines are optional extras (`pip install
'cnep-pipeline[dask]'` or `[ray]`), imported only when asked for. Without an address each starts a cluster on this
machine of `workers` one-thread processes (Dask's `LocalCluster`, a new Ray instance even where one that `ray start`
began is running); with one, it joins the user's cluster, whose workers need cnep installed. The engines report a unit
when it is done (the progress bar moves by whole units), not step by step as the local pool does.
"""

from __future__ import annotations

import contextlib
import importlib.util
from collections.abc import Callable, Iterator, Sequence

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate import addresses
from cnep.pipeline.evaluate.constants import EXECUTORS
from cnep.pipeline.workers import SMALL_MODEL_MALLOC, THREAD_VARIABLES, environment

# Ray gives a starting worker process a time to register (60 s by default); one that registers later leaves the run
# waiting with no end and no error, and a loaded machine slows a new process's start. The local instance allows more.
RAY_LOCAL_SETTINGS = {"worker_register_timeout_seconds": 600}
PACKAGES = {"dask": ("distributed", "dask[distributed]"), "ray": ("ray", "ray")}  # executor: (module, what to install)


def run_on_cluster(
    work: Callable, units: Sequence, executor: str, address: str | None, workers: int
) -> Iterator[tuple]:
    """Yield (unit, `work(unit)`) as the units finish on `executor` ("dask" or "ray"), at `address` (None: a cluster
    of `workers` processes started on this machine, stopped at the end)."""
    one_thread = environment({**dict.fromkeys(THREAD_VARIABLES, "1"), **SMALL_MODEL_MALLOC})  # inherited by workers
    with one_thread:
        if executor == "dask":
            yield from _on_dask(work, units, address, max(1, workers))
        elif executor == "ray":
            yield from _on_ray(work, units, address, max(1, workers))
        else:
            raise PipelineError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")


def check_cluster(executor: str, address: str | None) -> None:
    """Before any work: PipelineError, one line, where `executor` ("local", "dask" or "ray") cannot be used: its package
    is not installed, or no scheduler answers at `address` within the time limit (`addresses.reach`)."""
    if executor not in PACKAGES:
        return
    if importlib.util.find_spec(PACKAGES[executor][0]) is None:
        raise _missing(executor, PACKAGES[executor][1])
    if address is not None:
        addresses.reach(executor, address)


def _missing(executor: str, module: str) -> PipelineError:
    return PipelineError(
        f"--executor {executor} needs the {module} package: pip install 'cnep-pipeline[{executor}]' (on every "
        f"machine of the cluster too)"
    )


def _on_dask(work: Callable, units: Sequence, address: str | None, workers: int) -> Iterator[tuple]:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise _missing("dask", PACKAGES["dask"][1]) from None
    with contextlib.ExitStack() as held:
        if address is None:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
            held.enter_context(cluster)
            address = cluster.scheduler_address
        else:
            addresses.reach("dask", address)  # Dask's client would wait without end where no scheduler answers
        client = held.enter_context(Client(address, timeout=addresses.CONNECT_SECONDS))
        futures = {client.submit(work, unit, pure=False): unit for unit in units}
        for future in as_completed(futures):
            yield futures[future], future.result()


def _on_ray(work: Callable, units: Sequence, address: str | None, workers: int) -> Iterator[tuple]:
    try:
        import ray
    except ImportError:
        raise _missing("ray", PACKAGES["ray"][1]) from None
    if address is None:  # a new instance on this machine, not a cluster that `ray start` left running here
        ray.init(address="local", num_cpus=workers, include_dashboard=False, _system_config=RAY_LOCAL_SETTINGS)
    else:
        addresses.reach("ray", address)
        ray.init(address=address)
    try:
        remote = ray.remote(num_cpus=1)(work)
        pending = {remote.remote(unit): unit for unit in units}
        while pending:
            (ready,), _ = ray.wait(list(pending), num_returns=1)
            yield pending.pop(ready), ray.get(ready)
    finally:
        ray.shutdown()
