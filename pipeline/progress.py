"""One progress bar per stage that reads well in any terminal.

On a terminal (stderr is a TTY) it is a tqdm bar redrawn in place. Elsewhere (CI logs, `| tee`, a file)
there are no carriage returns: the bar's text is written as a whole line at most every
`LINE_INTERVAL_S` seconds while it runs, and once when it closes. With `quiet` (`cnep -q`) nothing.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from typing import Any, TextIO

from tqdm import tqdm

LINE_INTERVAL_S = 10.0  # seconds between progress lines when stderr is not a terminal
# For a total that grows while the stage runs (extract learns each file's frame count when it opens it):
# the count and the rate, no percentage or time left that would be wrong.
OPEN_ENDED_FORMAT = "{desc}: {n_fmt} {unit} [{elapsed}, {rate_fmt}{postfix}]"


class _Lines:
    """A file for tqdm that turns its in-place redraws ("\\r" + text) into whole lines, at most one per interval."""

    def __init__(self, stream: TextIO, interval_s: float) -> None:
        self.stream, self.interval_s = stream, interval_s
        self.current = self.written = ""
        self.last = time.monotonic()  # the first line comes after one interval, or at the end

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


class _Bar(tqdm):
    """A tqdm bar that, left by an exception, closes without its last line."""

    def __exit__(self, exc_type, exc_value, traceback):
        if exc_type is not None:
            _discard(self)
        return super().__exit__(exc_type, exc_value, traceback)


def progress_bar(
    iterable: Iterable | None = None,
    *,
    total: float | None = None,
    desc: str,
    unit: str,
    quiet: bool = False,
    open_ended: bool = False,
    stream: TextIO | None = None,
    **options: Any,
) -> tqdm:
    """A tqdm bar for one stage (see the module docstring); `stream` defaults to sys.stderr.

    open_ended: the total grows while the stage runs, so show the count and rate only.
    """
    stream = sys.stderr if stream is None else stream
    if open_ended:
        options["bar_format"] = OPEN_ENDED_FORMAT
    if quiet:
        return _Bar(iterable, total=total, disable=True)
    if stream.isatty():
        return _Bar(iterable, total=total, desc=desc, unit=unit, file=stream, dynamic_ncols=True, **options)
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
