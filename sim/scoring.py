"""What every task's scoring shares: the seconds each part of an episode took, as a row's and a table's figures, the
shares with their 95% intervals, and the columns of a task's table."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cnep.sim.statistics import wilson

TIMES = ("policy", "render", "physics")


def percentiles_ms(seconds: np.ndarray) -> dict[str, float]:
    """p50 and p99 of `seconds` (n,), in ms (0 for none)."""
    if not len(seconds):
        return {"p50": 0.0, "p99": 0.0}
    p50, p99 = np.percentile(np.asarray(seconds) * 1e3, (50, 99))
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2)}


def timings_ms(ep) -> dict[str, dict[str, float]]:
    """An episode's (sim.episode.EpisodeResult) p50 and p99 of each part of its steps (TIMES), in ms: its row's `ms`."""
    return {name: percentiles_ms(getattr(ep, f"{name}_s")) for name in TIMES}


def share(rows: list[dict], key: Callable[[dict], bool]) -> float:
    """The share of `rows` (at least one) for which `key` holds, to 4 decimals."""
    return round(sum(map(key, rows)) / len(rows), 4)


def shares(rows: list[dict], **keys: Callable[[dict], bool]) -> dict[str, float | list[float] | None]:
    """Per name of `keys`: the share of `rows` for which its key holds (`share`) and, under `NAME_ci`, its Wilson 95%
    interval [lower, upper] (sim.statistics.wilson), to 4 decimals; both None where there are no rows."""
    out: dict[str, float | list[float] | None] = {}
    for name, key in keys.items():
        out[name] = share(rows, key) if rows else None
        out[f"{name}_ci"] = [round(bound, 4) for bound in wilson(sum(map(key, rows)), len(rows))] if rows else None
    return out


def pooled_ms(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Per part of the steps (TIMES): the median of the episodes' p50 and the largest of their p99 (ms)."""
    return {
        name: {
            "p50": round(float(np.median([r["ms"][name]["p50"] for r in rows])), 2),
            "p99": max(r["ms"][name]["p99"] for r in rows),
        }
        for name in TIMES
    }


@dataclass(frozen=True)
class Column:
    """A column of a task's table on screen: head, its width in characters (0: as wide as its text, left-aligned, for
    the last column), and value(rates) the cell's text."""

    head: str
    width: int
    value: Callable[[dict], str]

    def cell(self, text: str) -> str:
        return f"{text:>{self.width}}" if self.width else text


def percent(key: str) -> Callable[[dict], str]:
    """A column's value: the rate under `key` as a whole percentage ("-" where it is None)."""
    return lambda rates: "-" if rates[key] is None else f"{rates[key]:.0%}"


def percent_ci(key: str) -> Callable[[dict], str]:
    """A column's value: the rate under `key` and its interval under `KEY_ci` as whole percentages, `92% [81-97]`
    ("-" where it is None); at most PERCENT_CI_WIDTH characters."""

    def value(rates: dict) -> str:
        if rates[key] is None:
            return "-"
        lo, hi = rates[f"{key}_ci"]
        return f"{rates[key]:.0%} [{lo * 100:.0f}-{hi * 100:.0f}]"

    return value


PERCENT_CI_WIDTH = 13  # characters of percent_ci's longest value, `100% [93-100]`


def decimals(key: str) -> Callable[[dict], str]:
    """A column's value: the figure under `key` to 2 decimals ("-" where it is None)."""
    return lambda rates: "-" if rates[key] is None else f"{rates[key]:.2f}"
