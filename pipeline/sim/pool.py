"""Closed-loop work spread over worker processes under one bar: `run_counted` runs calls (a policy's episodes, a
candidate's validation episodes) in single-threaded processes, each reporting its episodes to a bar of them all."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, wait
from multiprocessing import get_context
from queue import SimpleQueue
from typing import TypeVar

from cnep.pipeline.progress import REPORT_INTERVAL_S, RemoteBar, follow_total, progress_bar
from cnep.pipeline.workers import single_thread_processes

T = TypeVar("T")


def run_counted(calls: dict[str, Callable[..., T]], total: int, desc: str, workers: int, quiet: bool) -> dict[str, T]:
    """Every call of `calls` (label -> a picklable callable taking `bar=`, the RemoteBar its episodes go to) in
    `workers` single-threaded processes (0: in this one, one after another), one bar `desc` of `total` episodes;
    label -> its result, in the order of `calls`."""
    results: dict[str, T] = {}
    with progress_bar(total=total, desc=desc, unit="episode", quiet=quiet) as bar:
        if workers == 0:
            reports, counts = SimpleQueue(), {}
            for label, call in calls.items():
                results[label] = call(bar=RemoteBar(reports, label))
                follow_total(reports, bar, counts)
            return results
        with get_context("spawn").Manager() as manager, single_thread_processes(workers) as pool:
            reports, counts = manager.Queue(), {}
            pending = {pool.submit(call, bar=RemoteBar(reports, label)): label for label, call in calls.items()}
            while pending:
                finished, _ = wait(pending, timeout=REPORT_INTERVAL_S, return_when=FIRST_COMPLETED)
                follow_total(reports, bar, counts)
                for future in finished:
                    results[pending.pop(future)] = future.result()
    return {label: results[label] for label in calls}
