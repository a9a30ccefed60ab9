"""One closed-loop pick-and-place episode: a policy drives the pick-and-place environment by one of the obstacle
task's protocols (cnep.sim.episode, whose `Driver` turns reads into actions): PLANNED reads the first observation
only and executes its waypoints step by step; ONLINE conditions on every new frame and state and its next waypoint is
the next action. The gripper follows the policy's two-state command where it has one.

The policy is anything with `reset(seed)`, `step(observation) -> runtime.PolicyStep`, `action_names` and
`gripper` (a `cnep.runtime.Policy`, or a baseline behind the same interface), opened for PLANNED with waypoints
spanning the task's motion (the scene's MAX_STEPS).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cnep.runtime import STATE_KEY, Policy
from cnep.sim.episode import ONLINE, Driver
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.env import PickPlaceEnv


@dataclass
class PickEpisode:
    """A pick-and-place episode's outcome and its trace.

    seed: the reset seed; protocol: planned / online; condition: decided / free / changed; success, collision,
    lifted, dropped: the environment's verdicts at the end; place: the mat the bar ended on (a PLACES name) or None;
    valid: the valid places' names at the end; taken_start, taken_end: the places taken at the start and at the end
    (a bool each); change_step: the step at which the table changed (None: it did not); switch_step: the first step
    at or after the change at which the active expert changed (None: none did, no change, or PLANNED); switches:
    changes of the active expert over the episode (0 for PLANNED: one read). Per step: states (steps + 1, 8), bar
    (steps + 1, 7) the bar's position and quaternion xyzw, render_s / physics_s (seconds); per read of the policy
    (every step ONLINE, the first only PLANNED): gates (reads, d), experts (reads,), predicted (reads, W, 3),
    policy_s (seconds); frames (steps + 1, H, W, 3) when recorded, else None.
    """

    seed: int
    protocol: str
    condition: str
    success: bool
    collision: bool
    lifted: bool
    dropped: bool
    place: str | None
    valid: list[str]
    taken_start: list[bool]
    taken_end: list[bool]
    change_step: int | None
    switch_step: int | None
    switches: int
    states: np.ndarray
    bar: np.ndarray
    gates: np.ndarray
    experts: np.ndarray
    predicted: np.ndarray
    policy_s: np.ndarray
    render_s: np.ndarray
    physics_s: np.ndarray
    frames: np.ndarray | None = field(default=None, repr=False)


def run_pick_episode(
    env: PickPlaceEnv, policy: Policy, seed: int, protocol: str = ONLINE, record_frames: bool = False
) -> PickEpisode:
    """Run one episode of `env` (reset with `seed`) driven by `policy` (reset first with `seed`) by `protocol`."""
    observation, info = env.reset(seed=seed)
    policy.reset(seed=seed)
    driver = Driver(policy, protocol, observation)
    taken_start = list(info["taken"])
    trace: dict[str, list] = {k: [] for k in ("states", "bar", "frames")}
    times: dict[str, list] = {"render_s": [env.timings["render_s"]], "physics_s": []}
    for k in range(env.max_steps):
        _keep(trace, env, observation, record_frames)
        observation, _, terminated, truncated, info = env.step(driver.action(observation, k))
        times["render_s"].append(env.timings["render_s"])
        times["physics_s"].append(env.timings["physics_s"])
        if terminated or truncated:
            break
    _keep(trace, env, observation, record_frames)
    experts = np.asarray(driver.experts, dtype=np.int64)
    steps = len(trace["states"]) - 1
    change = info["change_step"] if info["change_step"] is not None and info["change_step"] < steps else None
    return PickEpisode(
        seed=seed,
        protocol=protocol,
        condition=info["condition"],
        success=bool(info["is_success"]),
        collision=bool(info["collision"]),
        lifted=bool(info["lifted"]),
        dropped=bool(info["dropped"]),
        place=None if info["place"] is None else P.PLACES[info["place"]][0],
        valid=[P.PLACES[i][0] for i in info["valid"]],
        taken_start=taken_start,
        taken_end=list(info["taken"]),
        change_step=change,
        switch_step=first_switch(experts, change),
        switches=int(np.count_nonzero(np.diff(experts))),
        states=np.asarray(trace["states"]),
        bar=np.asarray(trace["bar"]),
        gates=np.asarray(driver.gates),
        experts=experts,
        predicted=np.asarray(driver.predicted),
        policy_s=np.asarray(driver.policy_s),
        render_s=np.asarray(times["render_s"]),
        physics_s=np.asarray(times["physics_s"]),
        frames=np.asarray(trace["frames"]) if record_frames else None,
    )


def first_switch(experts: np.ndarray, change: int | None) -> int | None:
    """The first step at or after `change` whose active expert (`experts` (n,), one per step) differs from the
    step before's; None without a change or a switch. The table changes before the step `change` acts, so the
    policy first sees the change in its read at step `change + 1`."""
    if change is None:
        return None
    after = np.flatnonzero(np.diff(experts[change:]) != 0)
    return int(change + 1 + after[0]) if len(after) else None


def _keep(trace: dict, env: PickPlaceEnv, observation: dict, record_frames: bool) -> None:
    trace["states"].append(observation[STATE_KEY])
    trace["bar"].append(np.concatenate(env.object_pose()))
    if record_frames:
        trace["frames"].append(observation[env.image_key])
