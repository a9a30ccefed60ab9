"""`cnep sim grid`'s results: the CSV, a row per cell, protocol and condition (`cell_rows`, `csv_text`), and the table
pooled over demonstration sets and training seeds, per task, model, demonstrations per behaviour, protocol and
condition (`pooled_table`), which the results pages carry. Both read only the cells' rates, so the table is made
again from the CSV alone.

A CSV row: the cell (task, set, per_behaviour, the demonstrations trained on, model, train_seed), protocol, condition
(empty where the task has none), episodes, the reported episode seeds (`first-last`), then the task's rates (sim.tasks'
scoring: success, entropy, collision, the switching, ...) as numbers, each share's Wilson 95% interval as `NAME_lo`
and `NAME_hi`, counts by name as `name:count` words; empty where a rate is not defined.

The table's success pools the episodes of every set and seed of its line (their Wilson 95% interval beside it),
`runs` their number and `range` the lowest and highest success of one run, so the spread between training runs
shows beside the interval, which treats every episode as independent; entropy is the mean of the runs' behaviour
entropies (over the runs where it is defined).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable

from cnep.sim.statistics import wilson

CELL = ("task", "set", "per_behaviour", "demonstrations", "model", "train_seed")
LEAD = (*CELL, "protocol", "condition", "episodes", "episode_seeds")
LEFT_OUT = ("episodes", "ms", "per_episode")  # rates the row has as a lead column, or not at all
POOLED = ("task", "model", "per_behaviour", "protocol", "condition")
HEAD = ("task", "model", "per behaviour", "protocol", "condition", "runs", "episodes", "success [95% CI]", "range",
        "entropy")  # fmt: skip


def cell_rows(cell: dict) -> list[dict]:
    """The CSV rows of a cell (`cnep sim grid`'s cell file: the CELL keys and `results`, protocol -> rates or protocol
    -> condition -> rates), one per protocol and condition."""
    rows = []
    for protocol, results in cell["results"].items():
        by_condition = results.items() if "episodes" not in results else [("", results)]
        for condition, rates in by_condition:
            seeds = [r["seed"] for r in rates["per_episode"]]
            lead = {**{k: cell[k] for k in CELL}, "protocol": protocol, "condition": condition}
            rows.append({**lead, "episodes": rates["episodes"], "episode_seeds": f"{min(seeds)}-{max(seeds)}"})
            rows[-1].update(rate_columns(rates))
    return rows


def rate_columns(rates: dict) -> dict:
    """The rates (module docstring) as CSV columns: success and entropy first."""
    columns: dict = {}
    for key in dict.fromkeys(("success", "success_ci", "entropy", *rates)):
        value, name = rates[key], key.removesuffix("_ci")
        if key in LEFT_OUT:
            continue
        if key.endswith("_ci"):
            columns[f"{name}_lo"], columns[f"{name}_hi"] = value or ("", "")
        elif isinstance(value, dict):
            columns[key] = " ".join(f"{name}:{count}" for name, count in value.items())
        else:
            columns[key] = "" if value is None else value
    return columns


def csv_text(rows: list[dict]) -> str:
    """The CSV of `rows`: LEAD, then every other column in the order the rows first have it."""
    columns = list(dict.fromkeys(name for row in rows for name in row))
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=columns, restval="", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return stream.getvalue()


def read_rows(text: str) -> list[dict]:
    """The rows of a grid's CSV (`csv_text`), their values as text."""
    return list(csv.DictReader(io.StringIO(text)))


def pooled_table(rows: Iterable[dict]) -> str:
    """The Markdown table of `rows` (CSV rows, as `cell_rows` makes them or `read_rows` reads them) pooled per POOLED
    key (module docstring), in the rows' order."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(str(row[k]) for k in POOLED), []).append(row)
    lines = [f"| {' | '.join(HEAD)} |", "|---|---|---:|---|---|---:|---:|---|---|---:|"]
    for key, group in groups.items():
        n = sum(int(r["episodes"]) for r in group)
        successes = sum(round(float(r["success"]) * int(r["episodes"])) for r in group)
        lo, hi = wilson(successes, n)
        runs = [float(r["success"]) for r in group]
        entropies = [float(r["entropy"]) for r in group if r["entropy"] not in ("", None)]
        entropy = f"{sum(entropies) / len(entropies):.2f}" if entropies else "-"
        cells = [*key[:4], key[4] or "-", str(len(group)), str(n)]
        spread = f"{min(runs):.0%}-{max(runs):.0%}"
        lines.append(f"| {' | '.join(cells)} | {successes / n:.1%} [{lo:.1%}, {hi:.1%}] | {spread} | {entropy} |")
    return "\n".join(lines)
