"""An evaluation as a table of episodes: each episode's row (`episode_row`), the rates of a policy's episodes under
one protocol (`rates`), and the table printed on screen (`format_table`).

A row: the episode's seed, success, collision, the side it passed, the cue's side (None without a cue), min
clearance and distance to the goal (m), steps, expert switches and the policy / render / physics time per step
(p50, p99, ms). The rates: success, collision, the share that followed the cue, the share passing left, the share
of episodes with an expert switch (the scene never changes during an episode), over `episodes`.
"""

from __future__ import annotations

import numpy as np

from cnep.sim.episode import EpisodeResult

TIMES = ("policy", "render", "physics")


def percentiles_ms(seconds: np.ndarray) -> dict[str, float]:
    """p50 and p99 of `seconds` (n,), in ms (0 for none)."""
    if not len(seconds):
        return {"p50": 0.0, "p99": 0.0}
    p50, p99 = np.percentile(np.asarray(seconds) * 1e3, (50, 99))
    return {"p50": round(float(p50), 2), "p99": round(float(p99), 2)}


def episode_row(ep: EpisodeResult) -> dict:
    """One episode as a JSON-able row (module docstring)."""
    return {
        "seed": ep.seed,
        "success": ep.success,
        "collision": ep.collision,
        "side": ep.side,
        "cue_side": ep.cue_side,
        "clearance_m": round(ep.clearance_m, 4),
        "distance_to_goal_m": round(ep.distance_to_goal_m, 4),
        "steps": len(ep.states) - 1,
        "switches": ep.switches,
        "ms": {name: percentiles_ms(getattr(ep, f"{name}_s")) for name in TIMES},
    }


def rates(rows: list[dict]) -> dict:
    """The rates over episode rows (module docstring), with the rows under `per_episode`."""
    n = len(rows)

    def share(key) -> float:
        return round(sum(map(key, rows)) / n, 4)

    cued = [r for r in rows if r["cue_side"] is not None]
    return {
        "episodes": n,
        "success": share(lambda r: r["success"]),
        "collision": share(lambda r: r["collision"]),
        "left": share(lambda r: r["side"] == "left"),
        "switching": share(lambda r: r["switches"] > 0),
        "followed_cue": round(sum(r["side"] == r["cue_side"] for r in cued) / len(cued), 4) if cued else None,
        "min_clearance_m": min(r["clearance_m"] for r in rows),
        "ms": {name: pooled_ms(rows, name) for name in TIMES},
        "per_episode": rows,
    }


def pooled_ms(rows: list[dict], name: str) -> dict[str, float]:
    """The median of the episodes' p50 and the largest of their p99 (ms)."""
    return {
        "p50": round(float(np.median([r["ms"][name]["p50"] for r in rows])), 2),
        "p99": max(r["ms"][name]["p99"] for r in rows),
    }


def format_table(results: dict[str, dict[str, dict]]) -> str:
    """The on-screen table: one line per policy (a label: model and seed) and protocol."""
    head = (
        f"{'policy':<16} {'protocol':<8} {'episodes':>8} {'success':>8} {'collision':>9} {'left':>6} "
        f"{'cue':>6} {'switching':>9} {'min gap':>8} {'policy ms p50/p99':>18}"
    )
    lines = [head, "-" * len(head)]
    for label, protocols in results.items():
        for protocol, r in protocols.items():
            cue = "-" if r["followed_cue"] is None else f"{r['followed_cue']:.0%}"
            ms = r["ms"]["policy"]
            lines.append(
                f"{label:<16} {protocol:<8} {r['episodes']:>8} {r['success']:>8.0%} {r['collision']:>9.0%} "
                f"{r['left']:>6.0%} {cue:>6} {r['switching']:>9.0%} {r['min_clearance_m'] * 100:>6.1f}cm "
                f"{ms['p50']:>9.1f}/{ms['p99']:.1f}"
            )
    return "\n".join(lines)
