"""Work spread over workers under one bar: `as_finished` runs calls (`cnep evaluate`'s units of fits, the closed
loop's policies' episodes, a candidate's validation episodes, a grid unit's cells) in single-threaded processes here or
on a Dask or Ray cluster (pipeline.evaluate.executors), yielding each result as its call finishes; `run_counted`
collects them in order.

A call takes `bar=`, a RemoteBar its work done goes to (the count so far of the bar's unit, training steps or
episodes, under its label, or under labels of its parts: `RemoteBar.part`), and ends with a final report of it all.
The bar shows the sum of the latest counts: as they come while the calls run on this machine, and when each one ends
on a cluster (whose workers return their reports with the result).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, wait
from queue import SimpleQueue
from typing import TypeVar

from tqdm import tqdm

from cnep.pipeline.evaluate.constants import LOCAL
from cnep.pipeline.evaluate.executors import run_on_cluster
from cnep.pipeline.progress import REPORT_INTERVAL_S, RemoteBar, follow_total, progress_bar
from cnep.pipeline.workers import report_manager, single_thread_processes

T = TypeVar("T")


def run_counted(
    calls: dict[str, Callable[..., T]], total: int, desc: str, workers: int, quiet: bool, *, unit: str
) -> dict[str, T]:
    """Every call of `calls` (label -> a picklable callable taking `bar=`) in `workers` single-threaded processes (0:
    in this one, one after another), one bar `desc` of `total` `unit`s; label -> its result, in the order of
    `calls`."""
    results = dict(as_finished(calls, total, desc, workers, quiet, unit=unit))
    return {label: results[label] for label in calls}


def as_finished(
    calls: dict[str, Callable[..., T]],
    total: int,
    desc: str,
    workers: int,
    quiet: bool,
    executor: str = LOCAL,
    address: str | None = None,
    *,
    unit: str,
    noun: str = "done",
) -> Iterator[tuple[str, T]]:
    """Yield (label, result) of every call of `calls` (label -> a picklable callable taking `bar=`) as it finishes:
    `workers` at a time in single-threaded processes here (0: in this process, one after another), or on the
    cluster `executor` names at `address` (pipeline.evaluate.executors: None starts one of `workers` processes here).
    One bar `desc` of `total` `unit`s (what the calls count: "episode", "step"); its postfix, how many calls are
    done (`3/8 done`, or `noun` for "done": `3/8 units`) and the last one's label."""
    with progress_bar(total=total, desc=desc, unit=unit, quiet=quiet) as bar:
        for done, (label, result) in enumerate(_finishing(calls, workers, executor, address, bar), 1):
            bar.set_postfix_str(f"{done}/{len(calls)} {noun}, last {label}")
            yield label, result


def _finishing(
    calls: dict[str, Callable[..., T]], workers: int, executor: str, address: str | None, bar: tqdm
) -> Iterator[tuple[str, T]]:
    """`as_finished`'s calls run where it asks, (label, result) as each finishes, `bar` moved to the sum of the
    latest counts they have reported."""
    counts: dict[str, int] = {}
    if executor != LOCAL:
        reports = SimpleQueue()
        for (label, _), (result, reported) in run_on_cluster(
            _reporting, list(calls.items()), executor, address, workers
        ):
            for report in reported:
                reports.put(report)
            follow_total(reports, bar, counts)
            yield label, result
        return
    if workers == 0:
        followed = _Followed(bar, counts)
        for label, call in calls.items():
            yield label, call(bar=RemoteBar(followed, label))
        return
    with report_manager() as manager, single_thread_processes(workers) as pool:
        reports = manager.Queue()
        pending = {pool.submit(call, bar=RemoteBar(reports, label)): label for label, call in calls.items()}
        while pending:
            finished, _ = wait(pending, timeout=REPORT_INTERVAL_S, return_when=FIRST_COMPLETED)
            follow_total(reports, bar, counts)
            for future in finished:
                yield pending.pop(future), future.result()


def _reporting(labelled: tuple[str, Callable[..., T]]) -> tuple[T, list[tuple]]:
    """A call of `as_finished` on a cluster's worker: its result and the reports its bar was given, in order."""
    label, call = labelled
    reports: list[tuple] = []
    result = call(bar=RemoteBar(_Appending(reports), label))
    return result, reports


class _Followed:
    """The queue of the RemoteBars of calls run in this process: each report moves `bar` to the new sum at once."""

    def __init__(self, bar: tqdm, counts: dict[str, int]) -> None:
        self.bar, self.counts, self.reports = bar, counts, SimpleQueue()

    def put(self, report: tuple[str, int, dict[str, str]]) -> None:
        self.reports.put(report)
        follow_total(self.reports, self.bar, self.counts)


class _Appending:
    """The queue of a RemoteBar on a cluster's worker: its reports appended to a list, returned with the result."""

    def __init__(self, reports: list[tuple]) -> None:
        self.put = reports.append
