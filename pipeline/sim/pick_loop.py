"""A policy in the pick-and-place closed loop: `evaluate_pick_policy` runs it for `episodes` episodes by each
protocol (planned, online: cnep.sim.episode) in each condition (decided, free, changed), writes the first `record` of
each as Rerun recordings and returns the rates and rows (sim.tasks.pick_place.scoring).

Episode i of a condition is reset with seed `episode_seed + i`: every policy meets the same scenes, and the same seed
gives the same episode bit for bit. The demonstrations' scenes come from other seeds
(pipeline.sim.generate.DEMO_SEED_OFFSET), so every episode is unseen.
"""

from __future__ import annotations

from pathlib import Path

from cnep.pipeline.progress import progress_bar
from cnep.pipeline.sim.pick_rerun import write_pick_episode
from cnep.runtime import Policy
from cnep.sim.episode import run_episode
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.scoring import pick_rates, pick_row


def evaluate_pick_policy(
    policy: Policy,
    protocols: tuple[str, ...],
    conditions: tuple[str, ...],
    episodes: int,
    *,
    label: str,
    max_steps: int,
    episode_seed: int = 0,
    record: int = 0,
    recordings: Path | None = None,
    quiet: bool = False,
) -> dict[str, dict[str, dict]]:
    """Protocol -> condition -> rates (sim.tasks.pick_place.scoring.pick_rates) of `policy` (a runtime.Policy or a
    baseline behind its interface, its waypoints covering an episode for PLANNED) over `episodes` episodes each,
    truncated after `max_steps` control steps; recordings: the folder for `<label>-<protocol>-<condition>-seed<N>.rrd`,
    the first `record` episodes of each protocol and condition (None: none written)."""
    results: dict[str, dict[str, dict]] = {protocol: {} for protocol in protocols}
    for condition in conditions:
        env = PickPlaceEnv(condition, max_steps=max_steps)
        try:
            for protocol in protocols:
                rows = []
                bar = progress_bar(range(episodes), desc=f"{label} {protocol} {condition}", unit="episode", quiet=quiet)
                for i in bar:
                    seed = episode_seed + i
                    recorded = recordings is not None and i < record
                    ep = run_episode(env, policy, seed, protocol, record_frames=recorded)
                    if recorded:
                        name = f"{label}-{protocol}-{condition}-seed{seed}"
                        write_pick_episode(recordings / f"{name}.rrd", name, ep, policy.n_experts)
                    rows.append(pick_row(ep))
                results[protocol][condition] = pick_rates(rows)
        finally:
            env.close()
    return results
