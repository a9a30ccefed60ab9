"""The pick-and-place task's scoring: each episode's row (`pick_row`) and the rates of a policy's episodes by one
protocol in one condition (`pick_rates`).

A row: the episode's seed, success, collision, lifted, dropped, the place the bar ended on and the valid ones, the
change's step and the switch's (the changed condition), the expert switches, the steps and the policy / render /
physics time per step (p50, p99, ms). The rates over `episodes`: success (the bar at rest on a valid place),
collision (with a cup), lifted, dropped, the places used (episode counts by place), the share of episodes with an
expert switch; in the changed condition the switch latency (steps from the change to the first switch after it,
p50 over the episodes that switched) and the share that switched within SWITCH_WITHIN steps.
"""

from __future__ import annotations

import numpy as np

from cnep.sim.scoring import TIMES, percentiles_ms, pooled_ms
from cnep.sim.tasks.pick_place.episode import PickEpisode

SWITCH_WITHIN = 5  # steps: a switch this soon after the change counts as prompt


def pick_row(ep: PickEpisode) -> dict:
    """One episode as a JSON-able row (module docstring)."""
    return {
        "seed": ep.seed,
        "success": ep.success,
        "collision": ep.collision,
        "lifted": ep.lifted,
        "dropped": ep.dropped,
        "place": ep.place,
        "valid": ep.valid,
        "change_step": ep.change_step,
        "switch_step": ep.switch_step,
        "switches": ep.switches,
        "steps": len(ep.states) - 1,
        "ms": {name: percentiles_ms(getattr(ep, f"{name}_s")) for name in TIMES},
    }


def pick_rates(rows: list[dict]) -> dict:
    """The rates over episode rows (module docstring), with the rows under `per_episode`."""
    n = len(rows)

    def share(key) -> float:
        return round(sum(map(key, rows)) / n, 4)

    places: dict[str, int] = {}
    for r in rows:
        if r["place"] is not None:
            places[r["place"]] = places.get(r["place"], 0) + 1
    changed = [r for r in rows if r["change_step"] is not None]
    latencies = [r["switch_step"] - r["change_step"] for r in changed if r["switch_step"] is not None]
    return {
        "episodes": n,
        "success": share(lambda r: r["success"]),
        "collision": share(lambda r: r["collision"]),
        "lifted": share(lambda r: r["lifted"]),
        "dropped": share(lambda r: r["dropped"]),
        "places": dict(sorted(places.items())),
        "switching": share(lambda r: r["switches"] > 0),
        "switch_latency_p50": float(np.median(latencies)) if latencies else None,
        "switched_within": round(sum(x <= SWITCH_WITHIN for x in latencies) / len(changed), 4) if changed else None,
        "ms": {name: pooled_ms(rows, name) for name in TIMES},
        "per_episode": rows,
    }
