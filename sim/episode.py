"""One closed-loop episode of any task: a policy drives the environment from its camera frames and state, by one of two
protocols.

- PLANNED (the paper's protocol on the Baxter): the policy reads the first observation only; its waypoints for the
  whole episode are the plan, executed step by step by the controller (held at the last waypoint after it).
- ONLINE: the policy conditions on every new frame and state and its next waypoint is the next action.

The policy is a `cnep.runtime.Policy` (`step(observation) -> PolicyStep`: waypoints (W, dy) named by
`action_names`, the gate and the active expert), or anything with the same `reset`, `step`, `action_names` and
`gripper` (a baseline behind its interface), loaded for PLANNED with waypoints spanning the task's motion.
An action is the state with the predicted columns replaced by the waypoint's, the gripper by the policy's gripper
command where it has one (`Policy.gripper`: a threshold with hysteresis, applied to each planned waypoint in turn),
executed as a two-state gripper executes it: the environment's closed command (its action's lowest gripper value: the
fingers squeeze) or its open one (the highest), whatever width the recordings' closed value reads.
`Policy.reset(seed)` starts each episode with the episode's seed (the draw of `first_expert="sample"`).

`run_episode` records what every task records (`EpisodeResult`); the environment judges the episode
(`TabletopEnv.judge`), its task's result adding the task's verdicts.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from cnep.runtime import STATE_KEY, STATE_NAMES, TIMESTAMP_KEY, Policy, PolicyStep
from cnep.runtime.spec import GRIPPER
from cnep.sim import scene as S

if TYPE_CHECKING:
    from cnep.sim.tabletop import TabletopEnv

GRIPPER_INDEX = STATE_NAMES.index(GRIPPER)
PLANNED, ONLINE = "planned", "online"
PROTOCOLS = (PLANNED, ONLINE)


@dataclass(kw_only=True)
class EpisodeResult:
    """An episode's outcome and its trace, as every task records them (a task's result adds its own verdicts).

    seed: the environment's reset seed; protocol: planned / online; condition: the task's condition (None for a task
    without conditions); success, collision: the environment's verdicts at the end; switches: changes of the active
    expert (0 for PLANNED: one read). Per step: states (steps + 1, 8) the observed states, object_poses (steps + 1,
    7) the position and quaternion xyzw of the task's object (`TabletopEnv.object_pose`), render_s / physics_s the
    seconds each took; per read of the policy (every step ONLINE, the first only PLANNED): gates (reads, d), experts
    (reads,), predicted (reads, W, 3) the waypoints' xyz, policy_s (seconds); frames (steps + 1, H, W, 3) when
    recorded, else None.
    """

    seed: int
    protocol: str
    condition: str | None
    success: bool
    collision: bool
    switches: int
    states: np.ndarray
    object_poses: np.ndarray
    gates: np.ndarray
    experts: np.ndarray
    predicted: np.ndarray
    policy_s: np.ndarray
    render_s: np.ndarray
    physics_s: np.ndarray
    frames: np.ndarray | None = field(default=None, repr=False)

    @property
    def steps(self) -> int:
        """The control steps the episode ran."""
        return len(self.states) - 1


def run_episode(
    env: TabletopEnv, policy: Policy, seed: int, protocol: str = ONLINE, record_frames: bool = False
) -> EpisodeResult:
    """Run one episode of `env` (reset with `seed`) driven by `policy` (reset first with `seed`) by `protocol`; the
    environment's task judges it (its result type)."""
    observation, info = env.reset(seed=seed)
    policy.reset(seed=seed)
    gripper_states = (float(env.action_space.low[GRIPPER_INDEX]), float(env.action_space.high[GRIPPER_INDEX]))
    driver = Driver(policy, protocol, observation, gripper_states)
    infos = [info]
    trace: dict[str, list] = {k: [] for k in ("states", "object_poses", "frames")}
    times: dict[str, list] = {"render_s": [env.timings["render_s"]], "physics_s": []}
    for k in range(env.max_steps):
        _keep(trace, env, observation, record_frames)
        observation, _, terminated, truncated, info = env.step(driver.action(observation, k))
        times["render_s"].append(env.timings["render_s"])
        times["physics_s"].append(env.timings["physics_s"])
        infos.append(info)
        if terminated or truncated:
            break
    _keep(trace, env, observation, record_frames)
    experts = np.asarray(driver.experts, dtype=np.int64)
    return env.judge(
        infos,
        seed=seed,
        protocol=protocol,
        condition=info.get("condition"),
        success=bool(info["is_success"]),
        collision=bool(info["collision"]),
        switches=int(np.count_nonzero(np.diff(experts))),
        states=np.asarray(trace["states"]),
        object_poses=np.asarray(trace["object_poses"]),
        gates=np.asarray(driver.gates),
        experts=experts,
        predicted=np.asarray(driver.predicted),
        policy_s=np.asarray(driver.policy_s),
        render_s=np.asarray(times["render_s"]),
        physics_s=np.asarray(times["physics_s"]),
        frames=np.asarray(trace["frames"]) if record_frames else None,
    )


class Driver:
    """A policy's actions in one episode by a protocol (module docstring), with what each read of the policy gave.

    ONLINE reads the policy at every step and acts on its first waypoint; PLANNED reads it at step 0 only and acts
    on waypoint k at step k (the last one after the plan's end). An action (8,) is the observed state with the
    policy's columns replaced by the waypoint's and the gripper by the policy's command where it has one. Per read:
    gates (d,), experts (the active expert), predicted (W, 3) the waypoints' xyz, policy_s (seconds).
    Made at the episode's first observation, the policy reset: no plan yet, the gripper command the nearest to where
    the gripper is. gripper_states: the environment's closed and open gripper commands, which the action carries as
    the policy's command closes or opens (None: the command's own value).
    """

    def __init__(
        self, policy: Policy, protocol: str, observation: dict, gripper_states: tuple[float, float] | None = None
    ) -> None:
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
        self.policy, self.protocol = policy, protocol
        self.columns = [STATE_NAMES.index(name) for name in policy.action_names]
        self.xyz = [policy.action_names.index(name) for name in STATE_NAMES[:3]]
        self.commands_gripper = policy.gripper is not None and GRIPPER in policy.action_names
        self.gates: list[np.ndarray] = []
        self.experts: list[int] = []
        self.predicted: list[np.ndarray] = []
        self.policy_s: list[float] = []
        self._plan: PolicyStep | None = None
        self.gripper_states = gripper_states
        gripper = float(observation[STATE_KEY][GRIPPER_INDEX])
        self._command = policy.gripper.nearest(gripper) if self.commands_gripper else None

    def action(self, observation: dict, k: int) -> np.ndarray:
        """The action (8,) at control step `k` on `observation`, reading the policy where the protocol says."""
        if self.protocol == ONLINE or self._plan is None:
            self._plan = self._read(observation, k)
        waypoints = self._plan.waypoints
        action = observation[STATE_KEY].copy()
        action[self.columns] = waypoints[0 if self.protocol == ONLINE else min(k, len(waypoints) - 1)]
        if self.commands_gripper:
            self._command = self.policy.gripper.command(float(action[GRIPPER_INDEX]), self._command)
            action[GRIPPER_INDEX] = self._executed(self._command)
        return action

    def _executed(self, command: float) -> float:
        """The gripper value the action carries for the policy's `command` (one of its two values; a gripper the
        demonstrations never moved stays open, as they started)."""
        if self.gripper_states is None:
            return command
        closed, opened = self.gripper_states
        gripper = self.policy.gripper
        return closed if gripper.low < gripper.high and gripper.is_closed(command) else opened

    def _read(self, observation: dict, k: int) -> PolicyStep:
        start = time.perf_counter()
        read = self.policy.step({**observation, TIMESTAMP_KEY: k * S.CONTROL_PERIOD_S})
        self.policy_s.append(time.perf_counter() - start)
        self.gates.append(read.gate)
        self.experts.append(read.expert)
        self.predicted.append(read.waypoints[:, self.xyz])
        return read


def _keep(trace: dict, env: TabletopEnv, observation: dict, record_frames: bool) -> None:
    trace["states"].append(observation[STATE_KEY])
    trace["object_poses"].append(np.concatenate(env.object_pose()))
    if record_frames:
        trace["frames"].append(observation[env.image_key])
