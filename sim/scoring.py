"""What every task's scoring shares: the seconds each part of an episode took, as a row's and a table's figures."""

from __future__ import annotations

import numpy as np

TIMES = ("policy", "render", "physics")


def percentiles_ms(seconds: np.ndarray) -> dict[str, float]:
    """p50 and p99 of `seconds` (n,), in ms (0 for none)."""
    if not len(seconds):
        return {"p50": 0.0, "p99": 0.0}
    p50, p99 = np.percentile(np.asarray(seconds) * 1e3, (50, 99))
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2)}


def pooled_ms(rows: list[dict], name: str) -> dict[str, float]:
    """The median of the episodes' p50 and the largest of their p99 (ms)."""
    return {
        "p50": round(float(np.median([r["ms"][name]["p50"] for r in rows])), 2),
        "p99": max(r["ms"][name]["p99"] for r in rows),
    }
