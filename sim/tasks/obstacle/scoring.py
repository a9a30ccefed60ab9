"""The obstacle task's scoring: each episode's row (`episode_row`) and the rates of a policy's episodes under one
protocol (`rates`).

A row: the episode's seed, success, collision, the side it passed, the cue's side (None without a cue), min
clearance and distance to the goal (m), steps, expert switches and the policy / render / physics time per step
(p50, p99, ms). The rates: success, collision, the share that followed the cue, the share passing left, the share
of episodes with an expert switch (the scene never changes during an episode), over `episodes`.
"""

from __future__ import annotations

from cnep.sim.episode import EpisodeResult
from cnep.sim.scoring import TIMES, percentiles_ms, pooled_ms


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
