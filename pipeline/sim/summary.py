"""The closed loop's tables on screen: one line per policy and protocol (`format_table`, the obstacle task), one per
policy, protocol and condition (`format_pick_table`, the pick-and-place task).
"""

from __future__ import annotations

from cnep.sim.tasks.pick_place.scoring import SWITCH_WITHIN


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


def format_pick_table(results: dict[str, dict[str, dict[str, dict]]]) -> str:
    """The on-screen table: one line per policy (a label: model and seed), protocol and condition (the episodes per
    line are the summary's)."""
    head = (
        f"{'policy':<18} {'protocol':<8} {'condition':<9} {'success':>8} {'collision':>9} {'lifted':>7} "
        f"{f'switch<={SWITCH_WITHIN}':>9} {'latency':>7}  places"
    )
    lines = [head, "-" * len(head)]
    for label, protocols in results.items():
        for protocol, conditions in protocols.items():
            for condition, r in conditions.items():
                within = "-" if r["switched_within"] is None else f"{r['switched_within']:.0%}"
                latency = "-" if r["switch_latency_p50"] is None else f"{r['switch_latency_p50']:.0f}"
                places = " ".join(f"{k}:{v}" for k, v in r["places"].items())
                lines.append(
                    f"{label:<18} {protocol:<8} {condition:<9} {r['success']:>8.0%} {r['collision']:>9.0%} "
                    f"{r['lifted']:>7.0%} {within:>9} {latency:>7}  {places}"
                )
    return "\n".join(lines)
