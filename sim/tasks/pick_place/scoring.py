"""The pick-and-place task's scoring: an episode's result (`PickEpisode`, judged from its trace by `judge`), its row
(`pick_row`), the rates of a policy's episodes by one protocol in one condition (`pick_rates`), the table's COLUMNS
and what the summary says of the demonstrations (`describe_demonstrations`).

A row: the episode's seed, success, collision, lifted, dropped, the place the bar ended on and the valid ones, the
change's step (the changed condition, once the table changed), the first switch of the active expert, the first at or
after the change and the first after it to the expert of a valid place (`valid_switch_step`), the first read after it
whose plan ends on a valid place, by a switch or within an expert (`reroute_step`), the expert switches, how far the
gripper was from the bar's centre when first commanded to close (`grasp_offset_m`; None: it never closed), the steps and
the policy / render / physics time per step (p50, p99, ms). The rates over `episodes`: success (the bar at rest on a
valid place), collision (with a cup), lifted, dropped, the places used (episode counts by place), the share of episodes
with an expert switch (`switching`), and sim.scoring.change_rates': the share that switched while nothing had changed
(`switched_unchanged`: in decided and free scenes every switch; in changed scenes a switch before the policy could see
the change), the share of the changed episodes that switched to a valid place's expert within SWITCH_WITHIN steps of the
change (`switched_within`) and the median latency of such switches; the share of the changed episodes whose plan ended
on a valid place within SWITCH_WITHIN steps of the change, by either path (`rerouted_within`). Each share has its Wilson
95% interval under `NAME_ci` (sim.scoring.shares). `entropy`: the behaviour entropy of the place
(sim.statistics.behaviour_entropy) over the successful episodes whose scene left two valid places (free scenes, a
context per grasp); None where the scene left one (decided, changed). `grasp_offset_p50_m`: the median grasp offset of
the episodes whose gripper closed (None: none did).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnep.sim.episode import EpisodeResult
from cnep.sim.scoring import (
    CHANGE_COLUMNS,
    PERCENT_CI_WIDTH,
    SWITCH_WITHIN,
    Column,
    centimetres,
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
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.layout import PickLayout
from cnep.sim.tasks.pick_place.switching import counted_switch, rerouted


@dataclass(kw_only=True)
class PickEpisode(EpisodeResult):
    """A pick-and-place episode (sim.episode.EpisodeResult, its object the bar, its condition decided / free /
    changed): lifted, dropped, the environment's verdicts at the end; place, the mat the bar ended on (a PLACES name)
    or None; valid, the valid places' names at the end; taken_start, taken_end, the places taken at the start and at
    the end (a bool each); change_step, the step at which the table changed (None: it did not); switch_step, the
    first step at or after the change at which the active expert changed (None: none did, no change, or PLANNED);
    valid_after_change, the valid places' names right after the change (None without one); valid_switch_step, the
    first switch after the change to an expert whose plan ends on one of them (switching.counted_switch; None: none);
    reroute_step, the first read after the change whose plan ends on one of them (switching.rerouted; None: none);
    grasp_offset_m, the gripper's horizontal distance from the bar's centre when first commanded to close (None: never).
    """

    lifted: bool
    dropped: bool
    place: str | None
    valid: list[str]
    taken_start: list[bool]
    taken_end: list[bool]
    change_step: int | None
    switch_step: int | None
    valid_after_change: list[str] | None = None
    valid_switch_step: int | None = None
    reroute_step: int | None = None
    grasp_offset_m: float | None = None


def judge(infos: list[dict], layout: PickLayout = P.BAR, **recorded) -> PickEpisode:
    """The episode's result from the environment's `infos` (the reset's, then one per step) in `layout` and what
    sim.episode.run_episode `recorded`."""
    names = layout.names
    info = infos[-1]
    steps = len(recorded["states"]) - 1
    change = info["change_step"] if info["change_step"] is not None and info["change_step"] < steps else None
    after = info["valid_after_change"] if change is not None else None
    return PickEpisode(
        **recorded,
        lifted=bool(info["lifted"]),
        dropped=bool(info["dropped"]),
        place=None if info["place"] is None else names[info["place"]],
        valid=[names[i] for i in info["valid"]],
        taken_start=list(infos[0]["taken"]),
        taken_end=list(info["taken"]),
        change_step=change,
        switch_step=switch_after(recorded["experts"], change),
        valid_after_change=None if after is None else [names[i] for i in after],
        valid_switch_step=counted_switch(recorded["experts"], recorded["predicted"], change, after, layout),
        reroute_step=rerouted(recorded["predicted"], change, after, layout),
        grasp_offset_m=info["grasp_offset_m"],
    )


def switch_after(experts: np.ndarray, change: int | None) -> int | None:
    """The first step at or after `change` whose active expert (`experts` (n,), one per step) differs from the
    step before's; None without a change or a switch. The table changes before the step `change` acts, so the
    policy first sees the change in its read at step `change + 1`."""
    if change is None:
        return None
    after = np.flatnonzero(np.diff(experts[change:]) != 0)
    return int(change + 1 + after[0]) if len(after) else None


def rerouted_within(row: dict) -> bool:
    """Whether a changed episode's plan ended on a valid place within SWITCH_WITHIN steps of the change (rows of older
    runs lack `reroute_step`: never)."""
    step = row.get("reroute_step")
    return step is not None and step - row["change_step"] <= SWITCH_WITHIN


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
        "first_switch_step": first_switch(ep.experts),
        "switch_step": ep.switch_step,
        "valid_switch_step": ep.valid_switch_step,
        "reroute_step": ep.reroute_step,
        "switches": ep.switches,
        "grasp_offset_m": ep.grasp_offset_m,
        "steps": ep.steps,
        "ms": timings_ms(ep),
    }


def pick_rates(rows: list[dict]) -> dict:
    """The rates over episode rows (module docstring), with the rows under `per_episode`."""
    offsets = [r["grasp_offset_m"] for r in rows if r.get("grasp_offset_m") is not None]  # rows of older runs lack it
    places: dict[str, int] = {}
    for r in rows:
        if r["place"] is not None:
            places[r["place"]] = places.get(r["place"], 0) + 1
    return {
        "episodes": len(rows),
        **shares(
            rows,
            success=lambda r: r["success"],
            collision=lambda r: r["collision"],
            lifted=lambda r: r["lifted"],
            dropped=lambda r: r["dropped"],
        ),
        "places": dict(sorted(places.items())),
        **shares(rows, switching=lambda r: r["switches"] > 0),
        **change_rates(rows, change="change_step", switch="valid_switch_step"),
        **shares([r for r in rows if r["change_step"]], rerouted_within=rerouted_within),
        "entropy": behaviour_entropy((tuple(r["valid"]), r["place"]) for r in rows if r["success"]),
        "grasp_offset_p50_m": float(np.median(offsets)) if offsets else None,
        "ms": pooled_ms(rows),
        "per_episode": rows,
    }


COLUMNS = (
    Column("success", PERCENT_CI_WIDTH, percent_ci("success")),
    Column("collision", 9, percent("collision")),
    Column("lifted", 7, percent("lifted")),
    Column("grasp cm", 8, centimetres("grasp_offset_p50_m")),
    *CHANGE_COLUMNS,
    Column(f"reroute<={SWITCH_WITHIN}", PERCENT_CI_WIDTH, percent_ci("rerouted_within")),
    Column("entropy", 7, decimals("entropy")),
    Column("places", 0, lambda r: " ".join(f"{k}:{v}" for k, v in r["places"].items())),
)


def describe_demonstrations(places: list[str], layout: PickLayout = P.BAR) -> dict[str, dict[str, int]]:
    """How many demonstrations chose each place of `layout`."""
    return {"places": {name: places.count(name) for name in layout.names}}
