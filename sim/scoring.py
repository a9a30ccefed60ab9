"""What every task's scoring shares: the seconds each part of an episode took, as a row's and a table's figures, the
shares with their 95% intervals, the switching of the active expert with and without a change during the motion
(`change_rates`, `CHANGE_COLUMNS`), and the columns of a task's table."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cnep.sim.statistics import wilson

TIMES = ("policy", "render", "physics")
SWITCH_WITHIN = 5  # steps: a counted switch this soon after the change counts as prompt


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


def first_switch(experts: np.ndarray) -> int | None:
    """The first read (a step) whose active expert differs from the read before's, of `experts` (reads,); None: the
    expert never changed (PLANNED reads once)."""
    changed = np.flatnonzero(np.diff(experts) != 0)
    return int(changed[0] + 1) if len(changed) else None


def change_rates(rows: list[dict], change: str, switch: str) -> dict[str, float | list[float] | None]:
    """How a policy's expert switched, over rows that hold `first_switch_step` (first_switch), the step before whose
    action the scene changed during the motion under `change` (None or 0: no change after the reset) and the first
    counted switch after it under `switch` (one to an expert whose plan suits the changed scene; None: none).

    switched_unchanged: the share of `rows` whose expert switched while nothing had changed (without a change, or at
    or before the change's step: the policy first sees a change at the read after it); switched_within: the share of
    the changed rows with a counted switch within SWITCH_WITHIN steps of the change; each with its interval under
    `NAME_ci` (shares); switch_latency_p50: steps from the change to the counted switch, the median over the rows that
    made one (None: none did)."""
    changed = [r for r in rows if r[change]]
    latencies = [r[switch] - r[change] for r in changed if r[switch] is not None]
    return {
        **shares(rows, switched_unchanged=lambda r: unprompted(r, change)),
        **shares(changed, switched_within=lambda r: r[switch] is not None and r[switch] - r[change] <= SWITCH_WITHIN),
        "switch_latency_p50": float(np.median(latencies)) if latencies else None,
    }


def unprompted(row: dict, change: str) -> bool:
    """Whether the row's expert switched while nothing had changed (change_rates)."""
    first = row["first_switch_step"]
    return first is not None and (not row[change] or first <= row[change])


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


def centimetres(key: str) -> Callable[[dict], str]:
    """A column's value: the length under `key` (m) in cm to 1 decimal ("-" where it is None)."""
    return lambda rates: "-" if rates[key] is None else f"{100 * rates[key]:.1f}"


def latency_p50(rates: dict) -> str:
    """A column's value: the median steps from the change to the counted switch ("-" where none switched)."""
    return "-" if rates["switch_latency_p50"] is None else f"{rates['switch_latency_p50']:.0f}"


# Every task's switching columns: the switching while nothing had changed beside the prompt counted switches.
CHANGE_COLUMNS = (
    Column("no-change sw", PERCENT_CI_WIDTH, percent_ci("switched_unchanged")),
    Column(f"switch<={SWITCH_WITHIN}", PERCENT_CI_WIDTH, percent_ci("switched_within")),
    Column("latency", 7, latency_p50),
)
