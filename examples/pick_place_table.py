"""The pick-and-place results as a CSV and a markdown table, from the summaries `cnep sim pick-place` writes.

    python examples/pick_place_table.py OUT/summary.json [OUT2/summary.json ...] [--csv FILE]

One row per summary, model, training seed, protocol (planned, online) and condition: episodes, success and its
Wilson 95% interval (`_lo`, `_hi`), collision, lifted, dropped, the share of episodes with an expert switch and its
interval, the share that switched while nothing had changed and its interval (empty in a summary without it), the
share of changed episodes that switched to a valid place's expert within 5 steps, the median latency of such
switches (steps), the behaviour entropy of the place (free scenes; empty where it
is not defined) and the places the bar ended on (name:count). Prints the headline table in markdown, one row per model,
protocol and condition with a value per training seed (success, collision, switch within 5 steps); --csv FILE writes
every column (docs/results/pick-place.csv).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
from pathlib import Path

COLUMNS = ("run", "model", "train_seed", "protocol", "condition", "episodes", "success", "success_lo", "success_hi",
           "collision", "lifted", "dropped", "switching", "switching_lo", "switching_hi", "switched_unchanged",
           "switched_unchanged_lo", "switched_unchanged_hi", "switched_within_5",
           "switch_latency_p50", "entropy", "places")  # fmt: skip


def bounds(rates: dict, key: str) -> dict:
    """The Wilson interval of the rate under `key` as `KEY_lo` and `KEY_hi` (None where the rates hold none)."""
    lo, hi = rates.get(f"{key}_ci") or (None, None)
    return {f"{key}_lo": lo, f"{key}_hi": hi}


def rows(summary: Path) -> list[dict]:
    """The rows of one summary (module docstring)."""
    data = json.loads(summary.read_text())
    out = []
    for model, seeds in data["models"].items():
        for seed, protocols in seeds.items():
            for protocol, conditions in protocols.items():
                for condition, r in conditions.items():
                    out.append(
                        {
                            "run": summary.parent.name,
                            "model": model,
                            "train_seed": seed,
                            "protocol": protocol,
                            "condition": condition,
                            "episodes": r["episodes"],
                            "success": r["success"],
                            **bounds(r, "success"),
                            "collision": r["collision"],
                            "lifted": r["lifted"],
                            "dropped": r["dropped"],
                            "switching": r["switching"],
                            **bounds(r, "switching"),
                            "switched_unchanged": r.get("switched_unchanged"),
                            **bounds(r, "switched_unchanged"),
                            "switched_within_5": r["switched_within"],
                            "switch_latency_p50": r["switch_latency_p50"],
                            "entropy": r.get("entropy"),
                            "places": " ".join(f"{k}:{v}" for k, v in r["places"].items()),
                        }
                    )
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("summaries", type=Path, nargs="+", help="summary.json files of cnep sim pick-place")
    parser.add_argument("--csv", type=Path, help="write every row and column here")
    args = parser.parse_args(argv)
    table = [row for summary in args.summaries for row in rows(summary)]
    groups: dict[tuple, list[dict]] = {}
    for r in table:
        groups.setdefault((r["model"], r["protocol"], r["condition"]), []).append(r)
    print("| model (seeds) | protocol | condition | success | collision | switch within 5 steps |")
    print("|---|---|---|---|---|---|")
    for (model, protocol, condition), seeds in groups.items():
        names = ", ".join(str(r["train_seed"]) for r in seeds)
        print(f"| {model} ({names}) | {protocol} | {condition} | {_each(seeds, 'success')} | "
              f"{_each(seeds, 'collision')} | {_each(seeds, 'switched_within_5')} |")  # fmt: skip
    if args.csv:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(table)
        args.csv.write_text(buffer.getvalue())
    return table


def _each(seeds: list[dict], key: str) -> str:
    """The rows' `key` as percentages, one per training seed ("-" where a row has none): "86 / 84 / 92%"."""
    values = [r[key] for r in seeds]
    return "-" if None in values else " / ".join(f"{v:.0%}"[:-1] for v in values) + "%"


if __name__ == "__main__":
    main()
