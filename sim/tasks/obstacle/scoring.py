"""The obstacle task's scoring: an episode's result (`ObstacleEpisode`, judged from its trace by `judge`), its row
(`episode_row`), the rates of a policy's episodes under one protocol (`rates`), the table's COLUMNS and what the
summary says of the demonstrations (`describe_demonstrations`).

A row: the episode's seed, success, collision, the side it passed, the cue's side (None without a cue), the step the
cue showed (0: from the reset; None without a cue), min clearance and distance to the goal (m), steps, the first
switch of the active expert and the first after the cue to an expert passing on the cue's side (`cue_switch_step`),
the expert switches and the policy / render / physics time per step (p50, p99, ms). The rates: success, collision,
the share that followed the cue (of the episodes with a cue), the share passing left, the share of episodes with an
expert switch (`switching`), and sim.scoring.change_rates' with the cue shown during the motion as the change: the
share that switched while nothing had changed (`switched_unchanged`: without a cue, or with one shown from the
reset, every switch; else a switch before the policy could see the cue), the share of the episodes whose cue showed
during the motion that switched to the cue's side within SWITCH_WITHIN steps (`switched_within`) and the median
latency of such switches; each share over its episodes with its Wilson 95% interval under `NAME_ci`
(sim.scoring.shares); `entropy`, the behaviour entropy of the side passed (sim.statistics.behaviour_entropy: over
the successful episodes without a cue, where either side is free; None with a cue, which leaves one side).
"""

from __future__ import annotations

from dataclasses import dataclass

from cnep.sim.episode import EpisodeResult
from cnep.sim.scoring import (
    CHANGE_COLUMNS,
    PERCENT_CI_WIDTH,
    Column,
    change_rates,
    decimals,
    first_switch,
    percent,
    percent_ci,
    pooled_ms,
    shares,
    timings_ms,
)
from cnep.sim.statistics import behaviour_entropy
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.switching import counted_switch, side_of


@dataclass(kw_only=True)
class ObstacleEpisode(EpisodeResult):
    """An obstacle episode (sim.episode.EpisodeResult, its object the box): side, where the end effector passed the
    box ("left" / "right", facing the goal); clearance_m, the smallest gripper-box distance; distance_to_goal_m, at
    the end (xy); cue_side, the side the cue showed (None without a cue); contact_step, the first step touching the
    box, or None; cue_step, the step before whose action the cue showed (0: from the reset; None without a cue);
    cue_switch_step, the first switch after a cue that showed during the motion to an expert whose plan passes on its
    side (switching.counted_switch; None: none)."""

    side: str
    clearance_m: float
    distance_to_goal_m: float
    cue_side: str | None
    contact_step: int | None = None
    cue_step: int | None = None
    cue_switch_step: int | None = None


def judge(infos: list[dict], **recorded) -> ObstacleEpisode:
    """The episode's result from the environment's `infos` (the reset's, then one per step) and what
    sim.episode.run_episode `recorded`."""
    info = infos[-1]
    box = recorded["object_poses"][0, :2]  # where the box stood
    shown = info["cue_step"] or None  # a cue shown from the reset changes nothing during the motion
    return ObstacleEpisode(
        **recorded,
        side=side_of(recorded["states"][:, :2], box),
        clearance_m=float(info["clearance"]),
        distance_to_goal_m=float(info["distance_to_goal"]),
        cue_side=info["cue_side"],
        contact_step=next((k for k, step in enumerate(infos) if step["collision"]), None),
        cue_step=info["cue_step"],
        cue_switch_step=counted_switch(recorded["experts"], recorded["predicted"], shown, info["cue_side"], box),
    )


def episode_row(ep: ObstacleEpisode) -> dict:
    """One episode as a JSON-able row (module docstring)."""
    return {
        "seed": ep.seed,
        "success": ep.success,
        "collision": ep.collision,
        "side": ep.side,
        "cue_side": ep.cue_side,
        "cue_step": ep.cue_step,
        "clearance_m": round(ep.clearance_m, 4),
        "distance_to_goal_m": round(ep.distance_to_goal_m, 4),
        "steps": ep.steps,
        "first_switch_step": first_switch(ep.experts),
        "cue_switch_step": ep.cue_switch_step,
        "switches": ep.switches,
        "ms": timings_ms(ep),
    }


def rates(rows: list[dict]) -> dict:
    """The rates over episode rows (module docstring), with the rows under `per_episode`."""
    cued = [r for r in rows if r["cue_side"] is not None]
    return {
        "episodes": len(rows),
        **shares(
            rows,
            success=lambda r: r["success"],
            collision=lambda r: r["collision"],
            left=lambda r: r["side"] == "left",
            switching=lambda r: r["switches"] > 0,
        ),
        **shares(cued, followed_cue=lambda r: r["side"] == r["cue_side"]),
        **change_rates(rows, change="cue_step", switch="cue_switch_step"),
        "entropy": behaviour_entropy((choice(r), r["side"]) for r in rows if r["success"]),
        "min_clearance_m": min(r["clearance_m"] for r in rows),
        "ms": pooled_ms(rows),
        "per_episode": rows,
    }


def choice(row: dict) -> tuple[str, ...]:
    """The sides an episode's scene left to choose from: either without a cue, the cue's side with one."""
    return O.SIDES if row["cue_side"] is None else (row["cue_side"],)


COLUMNS = (
    Column("episodes", 8, lambda r: str(r["episodes"])),
    Column("success", PERCENT_CI_WIDTH, percent_ci("success")),
    Column("collision", 9, percent("collision")),
    Column("left", 6, percent("left")),
    Column("cue", 6, percent("followed_cue")),
    *CHANGE_COLUMNS,
    Column("entropy", 7, decimals("entropy")),
    Column("policy ms", 11, lambda r: "{p50:.1f}/{p99:.1f}".format(**r["ms"]["policy"])),  # p50/p99
)


def describe_demonstrations(sides: list[str]) -> dict[str, int]:
    """How many demonstrations passed each side."""
    return {side: sides.count(side) for side in O.SIDES}
