"""One progress bar per stage that reads well in any terminal, and bars fed by worker processes.

On a terminal (stderr is a TTY) it is a tqdm bar redrawn in place. Elsewhere (CI logs, `| tee`, a file)
there are no carriage returns: the bar's text is written as a whole line when it starts (what is about to
happen, and how much), at most every `LINE_INTERVAL_S` seconds while it runs, and once when it closes.
With `quiet` (`cnep -q`) nothing.

A worker process (a spawned pool's) reports through a `RemoteBar`: a label and a queue (a multiprocessing
Manager's) on which it puts its count and figures at most every REPORT_INTERVAL_S; the parent moves one bar per
label with `follow_reports`.

No step is silent for longer than about LINE_INTERVAL_S: an open bar is redrawn that often by a thread even when
nothing updates it (a long batch, a slow file), and a known long step that has no bar of its own (loading torch and
a stage's libraries, reading the frames that calibrate random weights, reading and packing the training files) runs
inside `heartbeat(what)`: a line naming it and the seconds it has taken that often, none when it ends sooner.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from queue import Empty
from typing import Any, TextIO

from tqdm import tqdm

LINE_INTERVAL_S = 5.0  # seconds between progress lines when stderr is not a terminal (never silent for ~10 s)
REPORT_INTERVAL_S = 0.5  # seconds between a worker's reports to its parent's bar


class _Lines:
    """A file for tqdm that turns its in-place redraws ("\\r" + text) into whole lines, at most one per interval."""

    def __init__(self, stream: TextIO, interval_s: float) -> None:
        self.stream, self.interval_s = stream, interval_s
        self.current = self.written = ""
        self.last = -float("inf")  # the first draw is written at once

    def write(self, text: str) -> None:
        drawn = [part.rstrip() for part in text.split("\r") if part.strip()]
        if drawn:
            self.current = drawn[-1].rstrip("\n")
        if "\n" in text:  # tqdm closes the bar: its final state
            self._emit()

    def flush(self) -> None:
        if time.monotonic() - self.last >= self.interval_s:
            self._emit()

    def _emit(self) -> None:
        if self.current and self.current != self.written:
            self.stream.write(self.current + "\n")
            self.stream.flush()
            self.written = self.current
        self.last = time.monotonic()


def _discard(bar: tqdm) -> None:
    """Close `bar` without its last line (cleared on a terminal): the error line that follows stands alone."""
    lines = getattr(bar.fp, "_wrapped", bar.fp) if hasattr(bar, "fp") else None
    if isinstance(lines, _Lines):
        lines.current = lines.written  # nothing left to write
    bar.leave = False
    bar.close()


def discard_bars() -> None:
    """Close every live bar without its last line (a stage failed, its error line follows)."""
    for bar in list(tqdm._instances):
        _discard(bar)


class _Ticker:
    """Calls `tick()` every LINE_INTERVAL_S on a thread of its own until `stop()`: a step that holds the main thread
    (an import, a long batch, a read) still lets it run."""

    def __init__(self, tick: Callable[[], None]) -> None:
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(tick,), name="progress-ticker", daemon=True)
        self._thread.start()

    def _run(self, tick: Callable[[], None]) -> None:
        while not self._stopped.wait(LINE_INTERVAL_S):
            tick()

    def stop(self) -> None:
        self._stopped.set()
        if self._thread is not threading.current_thread():
            self._thread.join()


class _Bar(tqdm):
    """A tqdm bar redrawn every LINE_INTERVAL_S while it is open, even when nothing updates it (its clock and time
    left move), and that, left by an exception, closes without its last line."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._ticker = None if self.disable else _Ticker(partial(_redraw, weakref.ref(self)))

    def close(self) -> None:
        if getattr(self, "_ticker", None) is not None:
            self._ticker.stop()
            self._ticker = None
        super().close()

    def __exit__(self, exc_type, exc_value, traceback):
        if exc_type is not None:
            _discard(self)
        return super().__exit__(exc_type, exc_value, traceback)


def _redraw(bar: weakref.ref) -> None:
    """Redraw the bar if it is still open (the ticker holds only a weak reference: a bar nobody keeps is dropped)."""
    live = bar()
    if live is not None and not live.disable:
        live.refresh()


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: float | None = None,
    desc: str,
    unit: str,
    quiet: bool = False,
    stream: TextIO | None = None,
    **options: Any,
) -> tqdm:
    """A tqdm bar for one stage (see the module docstring); `stream` defaults to sys.stderr."""
    stream = sys.stderr if stream is None else stream
    if quiet:
        return _Bar(iterable, total=total, disable=True)
    if stream.isatty():
        return _Bar(iterable, total=total, desc=desc, unit=unit, file=stream, dynamic_ncols=True, **options)
    options.setdefault("position", 0)  # several bars at once: whole lines each, no cursor moves between them
    return _Bar(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        file=_Lines(stream, LINE_INTERVAL_S),
        mininterval=LINE_INTERVAL_S,
        ascii=True,
        **options,
    )


@dataclass
class RemoteBar:
    """A worker's side of a bar its parent draws: `update(n, **figures)` puts (label, n, figures) on `queue`, at most
    every REPORT_INTERVAL_S unless `final`; picklable, so it travels with a job to a spawned process.

    n: the count so far (absolute, not an increment); figures: the bar's postfix, already formatted.
    """

    queue: Any  # a multiprocessing Manager's Queue (its proxy pickles)
    label: str
    _last: float = field(default=-float("inf"), repr=False)

    def update(self, n: int, final: bool = False, **figures: str) -> None:
        now = time.monotonic()
        if final or now - self._last >= REPORT_INTERVAL_S:
            self.queue.put((self.label, n, figures))
            self._last = now

    def part(self, name: str) -> RemoteBar:
        """A bar on the same queue under the label `LABEL-name`: a part of this bar's job, whose count `follow_total`
        adds to the other parts'."""
        return RemoteBar(self.queue, f"{self.label}-{name}")


class BarQueue:
    """The queue of a `RemoteBar` whose job runs in this process: each report moves `bar` at once."""

    def __init__(self, bar: tqdm) -> None:
        self.bar = bar

    def put(self, report: tuple[str, int, dict[str, str]]) -> None:
        _, n, figures = report
        self.bar.set_postfix(figures, refresh=False)
        self.bar.update(n - self.bar.n)


def follow_reports(queue: Any, bars: Mapping[str, tqdm]) -> None:
    """Move `bars` (label -> bar) to every report that `RemoteBar`s have put on `queue` so far, and redraw them (their
    clocks run while a worker starts); returns at once. A bar's rate and time left count from its first report."""
    while True:
        try:
            label, n, figures = queue.get_nowait()
        except Empty:
            break
        bar = bars[label]
        if bar.n == 0 and n > 0:
            bar.reset(total=bar.total)  # the worker has started: steps per second from here
        bar.set_postfix(figures, refresh=False)
        bar.update(n - bar.n)
    for bar in bars.values():
        bar.refresh()


class StageClock:
    """`with clock(name, number):` logs `[number/total] name` to `log` at a stage's start and, when it completes,
    its wall time (s) into `seconds` (which holds its start time, from `time.perf_counter`, while it runs)."""

    def __init__(self, seconds: dict[str, float], total: int, log: logging.Logger):
        self.seconds, self.total, self.log = seconds, total, log

    @contextmanager
    def __call__(self, name: str, number: int) -> Iterator[None]:
        self.log.info("[%d/%d] %s", number, self.total, name)
        self.seconds[name] = time.perf_counter()
        yield
        self.seconds[name] = round(time.perf_counter() - self.seconds[name], 2)
        self.log.info("%s done in %.1f s", name, self.seconds[name])


@contextmanager
def heartbeat(what: str, quiet: bool = False, stream: TextIO | None = None) -> Iterator[None]:
    """While the block runs, write `what ... N s` (the wall time so far) every LINE_INTERVAL_S to `stream`
    (sys.stderr); nothing with `quiet`, nothing when the block ends within the first interval."""
    if quiet:
        yield
        return
    stream = sys.stderr if stream is None else stream
    start = time.monotonic()

    def beat() -> None:
        stream.write(f"{what} ... {time.monotonic() - start:.0f} s\n")
        stream.flush()

    ticker = _Ticker(beat)
    try:
        yield
    finally:
        ticker.stop()


def follow_total(queue: Any, bar: tqdm, counts: dict[str, int]) -> None:
    """Move `bar` to the sum of the latest counts the `RemoteBar`s of several jobs have put on `queue` so far (label ->
    count, kept in `counts` between calls), and redraw it; returns at once."""
    while True:
        try:
            label, n, _ = queue.get_nowait()
        except Empty:
            break
        counts[label] = n
    bar.update(sum(counts.values()) - bar.n)
    bar.refresh()
