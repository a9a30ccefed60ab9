"""One closed-loop pick-and-place episode: a policy conditions on every new frame and state (the online protocol)
and its next waypoint is the next action, the gripper by the policy's two-state command where it has one.

The policy is anything with `reset(seed)`, `step(observation) -> runtime.PolicyStep`, `action_names` and
`gripper` (a `cnep.runtime.Policy`, or a baseline behind the same interface).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cnep.runtime import STATE_KEY, STATE_NAMES, TIMESTAMP_KEY, Policy
from cnep.runtime.spec import GRIPPER
from cnep.sim import pick_scene as P
from cnep.sim import scene as S
from cnep.sim.pick_env import PickPlaceEnv

GRIPPER_INDEX = STATE_NAMES.index(GRIPPER)


@dataclass
class PickEpisode:
    """A pick-and-place episode's outcome and its trace.

    seed: the reset seed; condition: decided / free / changed; success, collision, lifted, dropped: the
    environment's verdicts at the end; place: the mat the bar ended on (a PLACES name) or None; valid: the valid
    places' names at the end; taken_start, taken_end: the places taken at the start and at the end (a bool each);
    change_step: the step at which the table changed (None: it did not); switch_step: the first step at or after
    the change at which the active expert changed (None: none did, or no change); switches: changes of the active
    expert over the episode. Per step: states (steps + 1, 8), bar (steps + 1, 7) the bar's position and quaternion
    xyzw, gates (steps, d), experts (steps,), predicted (steps, W, 3), policy_s / render_s / physics_s (seconds);
    frames (steps + 1, H, W, 3) when recorded, else None.
    """

    seed: int
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


def run_pick_episode(env: PickPlaceEnv, policy: Policy, seed: int, record_frames: bool = False) -> PickEpisode:
    """Run one episode of `env` (reset with `seed`) driven online by `policy` (reset first with `seed`)."""
    observation, info = env.reset(seed=seed)
    policy.reset(seed=seed)
    taken_start = list(info["taken"])
    columns = [STATE_NAMES.index(name) for name in policy.action_names]
    xyz = [policy.action_names.index(name) for name in STATE_NAMES[:3]]
    trace: dict[str, list] = {k: [] for k in ("states", "bar", "frames", "gates", "experts", "predicted")}
    times: dict[str, list] = {"policy_s": [], "render_s": [env.timings["render_s"]], "physics_s": []}
    gripper = policy.gripper is not None and GRIPPER in policy.action_names
    command = policy.gripper.nearest(float(observation[STATE_KEY][GRIPPER_INDEX])) if gripper else None
    for k in range(env.max_steps):
        _keep(trace, env, observation, record_frames)
        start = time.perf_counter()
        read = policy.step({**observation, TIMESTAMP_KEY: k * S.CONTROL_PERIOD_S})
        times["policy_s"].append(time.perf_counter() - start)
        trace["gates"].append(read.gate)
        trace["experts"].append(read.expert)
        trace["predicted"].append(read.waypoints[:, xyz])
        action = observation[STATE_KEY].copy()
        action[columns] = read.waypoints[0]
        if gripper:
            command = policy.gripper.command(float(action[GRIPPER_INDEX]), command)
            action[GRIPPER_INDEX] = command
        observation, _, terminated, truncated, info = env.step(action)
        times["render_s"].append(env.timings["render_s"])
        times["physics_s"].append(env.timings["physics_s"])
        if terminated or truncated:
            break
    _keep(trace, env, observation, record_frames)
    experts = np.asarray(trace["experts"], dtype=np.int64)
    change = info["change_step"] if info["change_step"] is not None and info["change_step"] < len(experts) else None
    return PickEpisode(
        seed=seed,
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
        gates=np.asarray(trace["gates"]),
        experts=experts,
        predicted=np.asarray(trace["predicted"]),
        policy_s=np.asarray(times["policy_s"]),
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
