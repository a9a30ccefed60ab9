"""One closed-loop episode: a policy drives the environment from its camera frames and state, by one of two protocols.

- PLANNED (the paper's protocol on the Baxter): the policy reads the first observation only; its waypoints for the
  whole episode are the plan, executed step by step by the controller (held at the last waypoint after it).
- ONLINE: the policy conditions on every new frame and state and its next waypoint is the next action.

The policy is a `cnep.runtime.Policy` (`step(observation) -> PolicyStep`: waypoints (W, dy) named by
`action_names`, the gate and the active expert), loaded with waypoints >= the episode's steps for PLANNED.
An action is the state with the predicted columns replaced by the waypoint's, the gripper by the policy's gripper
command where it has one (`Policy.gripper`: a threshold with hysteresis, applied to each planned waypoint in turn).
`Policy.reset(seed)` starts each episode with the episode's seed (the draw of `first_expert="sample"`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cnep.runtime import STATE_KEY, STATE_NAMES, TIMESTAMP_KEY, Policy, PolicyStep
from cnep.runtime.spec import GRIPPER
from cnep.sim import scene as S
from cnep.sim.env import IMAGE_KEY, ObstacleEnv

GRIPPER_INDEX = STATE_NAMES.index(GRIPPER)
PLANNED, ONLINE = "planned", "online"
PROTOCOLS = (PLANNED, ONLINE)


@dataclass
class EpisodeResult:
    """An episode's outcome and its trace.

    seed: the environment's reset seed; success, collision: the environment's verdicts at the end; side: where the
    end effector passed the box ("left" / "right", facing the goal); clearance_m: the smallest gripper-box distance;
    distance_to_goal_m: at the end (xy); switches: changes of the active expert (0 for PLANNED: one read);
    cue_side: the side the cue showed (None without a cue). Per step: states (steps + 1, 8) the observed states,
    box (steps + 1, 7) the box's position and quaternion xyzw, gates (reads, d), experts (reads,), predicted
    (reads, W, 3) the waypoints' xyz, policy_s / render_s / physics_s the seconds each part took (policy per read).
    frames (steps + 1, H, W, 3) when recorded, else None; contact_step: the first step touching the box, or None.
    """

    seed: int
    protocol: str
    success: bool
    collision: bool
    side: str
    clearance_m: float
    distance_to_goal_m: float
    switches: int
    cue_side: str | None
    states: np.ndarray
    box: np.ndarray
    gates: np.ndarray
    experts: np.ndarray
    predicted: np.ndarray
    policy_s: np.ndarray
    render_s: np.ndarray
    physics_s: np.ndarray
    contact_step: int | None = None
    frames: np.ndarray | None = field(default=None, repr=False)


def run_episode(
    env: ObstacleEnv, policy: Policy, seed: int, protocol: str = ONLINE, record_frames: bool = False
) -> EpisodeResult:
    """Run one episode of `env` (reset with `seed`) driven by `policy` (reset first) by `protocol`."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    observation, info = env.reset(seed=seed)
    policy.reset(seed=seed)
    columns = [STATE_NAMES.index(name) for name in policy.action_names]
    trace: dict[str, list] = {k: [] for k in ("states", "box", "frames", "gates", "experts", "predicted")}
    times: dict[str, list] = {"policy_s": [], "render_s": [env.timings["render_s"]], "physics_s": []}
    plan: PolicyStep | None = None
    contact_step = None
    command = policy.gripper.nearest(float(observation[STATE_KEY][GRIPPER_INDEX])) if policy.gripper else None
    for k in range(env.max_steps):
        _keep(trace, env, observation, record_frames)
        if protocol == ONLINE or plan is None:
            plan = _read(policy, observation, k, trace, times)
        action = observation[STATE_KEY].copy()
        action[columns] = plan.waypoints[0 if protocol == ONLINE else min(k, len(plan.waypoints) - 1)]
        if policy.gripper is not None and GRIPPER in policy.action_names:
            command = policy.gripper.command(float(action[GRIPPER_INDEX]), command)
            action[GRIPPER_INDEX] = command
        observation, _, terminated, truncated, info = env.step(action)
        times["render_s"].append(env.timings["render_s"])
        times["physics_s"].append(env.timings["physics_s"])
        if info["collision"] and contact_step is None:
            contact_step = k + 1
        if terminated or truncated:
            break
    _keep(trace, env, observation, record_frames)
    experts = np.asarray(trace["experts"], dtype=np.int64)
    states = np.asarray(trace["states"])
    return EpisodeResult(
        seed=seed,
        protocol=protocol,
        success=bool(info["is_success"]),
        collision=bool(info["collision"]),
        side=side_passed(states),
        clearance_m=float(info["clearance"]),
        distance_to_goal_m=float(info["distance_to_goal"]),
        switches=int(np.count_nonzero(np.diff(experts))),
        cue_side=info["cue_side"],
        states=states,
        box=np.asarray(trace["box"]),
        gates=np.asarray(trace["gates"]),
        experts=experts,
        predicted=np.asarray(trace["predicted"]),
        policy_s=np.asarray(times["policy_s"]),
        render_s=np.asarray(times["render_s"]),
        physics_s=np.asarray(times["physics_s"]),
        contact_step=contact_step,
        frames=np.asarray(trace["frames"]) if record_frames else None,
    )


def _read(policy: Policy, observation: dict, k: int, trace: dict, times: dict) -> PolicyStep:
    """The policy's step on `observation` at control step `k`, its time, gate, expert and xyz waypoints kept."""
    start = time.perf_counter()
    plan = policy.step({**observation, TIMESTAMP_KEY: k * S.CONTROL_PERIOD_S})
    times["policy_s"].append(time.perf_counter() - start)
    trace["gates"].append(plan.gate)
    trace["experts"].append(plan.expert)
    trace["predicted"].append(plan.waypoints[:, [policy.action_names.index(name) for name in STATE_NAMES[:3]]])
    return plan


def side_passed(states: np.ndarray) -> str:
    """Where a path of states (n, >= 2) passed the box: "left" (x < 0) or "right", at the step nearest the box's y."""
    return "left" if states[int(np.abs(states[:, 1]).argmin()), 0] < 0 else "right"


def _keep(trace: dict, env: ObstacleEnv, observation: dict, record_frames: bool) -> None:
    trace["states"].append(observation[STATE_KEY])
    trace["box"].append(np.concatenate(env.box_pose()))
    if record_frames:
        trace["frames"].append(observation[IMAGE_KEY])
