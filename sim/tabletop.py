"""`TabletopEnv`: what every task's Gymnasium environment shares: the MuJoCo model with the floating gripper welded to
its mocap target (sim.scene.gripper_xml), the fixed camera, LeRobot's observation keys, the action (the next
waypoint) driving the mocap target for one control period, and the state a robot reports.

Observation: `observation.images.<camera>` (height, width, 3) uint8 and `observation.state` (8,) float32,
runtime.spec.STATE_NAMES: the end effector's xyz (m), its quaternion xyzw and the gripper's opening (m, each
finger's travel), at STATE_RESOLUTION. Action (8,) float32 in the same layout, clipped to the workspace.

A task's environment adds `reset`, `step` and two hooks, as Gymnasium's MuJoCo environments add `reset_model`:
`object_pose()` (the task's object, traced through an episode) and `judge(infos, **recorded)` (an episode's result,
sim.episode.run_episode's, from the environment's infos: its task's scoring).

The robot (sim.robot.RobotSettings): without a speed limit (TELEPORT) the mocap target jumps to each waypoint; with one
(ARM) it follows the waypoints within the arm's limits (sim.controller.Follower). Its sensing adds noise to the state
and the frames and draws the camera's pose and the light per episode (sim.noise), from generators seeded by the
episode's seed. `latency_steps` delays every action by that many control steps (the first ones hold the gripper
where the reset put it); `frames=False` leaves the camera out of the observation (nothing rendered).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

import gymnasium as gym
import mujoco
import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX, STATE_KEY
from cnep.sim import scene as S
from cnep.sim.controller import Follower
from cnep.sim.episode import EpisodeResult
from cnep.sim.noise import CameraDraw, noisy_frame, noisy_pose
from cnep.sim.render import Camera
from cnep.sim.robot import TELEPORT, RobotSettings

HOME_QUAT_XYZW = np.array([0.0, 0.0, 0.0, 1.0])


class TabletopEnv(gym.Env):
    """A tabletop task's environment: `xml` its MJCF (with the gripper of sim.scene), frames (height, width) from
    the camera `camera` (none with `frames` False), the gripper's opening up to `finger_open` m, `max_steps` control
    steps an episode, the `robot` that moves and senses, each action acting `latency_steps` control steps late."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": round(1 / S.CONTROL_PERIOD_S)}

    def __init__(
        self,
        xml: str,
        *,
        height: int,
        width: int,
        camera: str,
        finger_open: float,
        max_steps: int,
        render_mode: str | None = None,
        robot: RobotSettings = TELEPORT,
        latency_steps: int = 0,
        frames: bool = True,
    ) -> None:
        if latency_steps < 0:
            raise ValueError(f"latency_steps must be >= 0 (control steps an action acts late), got {latency_steps}")
        self.render_mode, self.max_steps = render_mode, max_steps
        self.robot, self.latency_steps, self.frames = robot, latency_steps, frames
        self.image_key = IMAGE_KEY_PREFIX + camera
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.camera = Camera(self.model, height, width, camera) if frames or render_mode else None
        self.workspace_low = np.array([-S.TABLE_HALF[0], -S.TABLE_HALF[1], 0.03, -1, -1, -1, -1, 0.0], np.float32)
        self.workspace_high = np.array([S.TABLE_HALF[0], S.TABLE_HALF[1], 0.3, 1, 1, 1, 1, finger_open], np.float32)
        spaces = {STATE_KEY: gym.spaces.Box(-np.inf, np.inf, (len(self.workspace_low),), dtype=np.float32)}
        if frames:
            spaces = {self.image_key: gym.spaces.Box(0, 255, (height, width, 3), dtype=np.uint8), **spaces}
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = gym.spaces.Box(self.workspace_low, self.workspace_high, dtype=np.float32)
        m = self.model
        gripper = m.body(S.GRIPPER_BODY).id
        self.gripper_geoms = {g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] == gripper}
        self._mocap = m.body(S.MOCAP_BODY).mocapid[0]
        self._fingers = [m.actuator(name).id for name in S.FINGER_JOINTS]
        self._finger_qpos = [m.jnt_qposadr[m.joint(name).id] for name in S.FINGER_JOINTS]
        self.timings = {"physics_s": 0.0, "render_s": 0.0}
        self._follower = Follower(robot, m.opt.timestep, S.CONTROL_PERIOD_S) if robot.max_speed is not None else None
        self._camera_draw = CameraDraw(m, camera)
        self._late: deque[np.ndarray] = deque()
        self._pose_rng = self._pixel_rng = None

    def place_gripper(self, xyz: np.ndarray, opening: float) -> None:
        """Put the gripper (and its mocap target) at `xyz` (m) in the home orientation, its fingers `opening` m, and
        start the robot's episode there: the controller at rest, the late actions holding it, the episode's draws of
        the robot's sensing (from the environment's generator)."""
        d = self.data
        root = self.model.jnt_qposadr[self.model.body(S.GRIPPER_BODY).jntadr[0]]
        d.qpos[root : root + 3] = xyz
        d.mocap_pos[self._mocap] = xyz
        d.qpos[self._finger_qpos] = opening
        d.ctrl[self._fingers] = opening
        if self._follower is not None:
            self._follower.reset(xyz, np.roll(HOME_QUAT_XYZW, 1))
        hold = np.array([*xyz, *HOME_QUAT_XYZW, opening])
        self._late = deque(hold.copy() for _ in range(self.latency_steps))
        if self.robot.randomised:
            seeds = np.random.SeedSequence(int(self.np_random.integers(2**63))).spawn(3)
            self._pose_rng, self._pixel_rng, camera_rng = (np.random.default_rng(seed) for seed in seeds)
            self._camera_draw.draw(camera_rng, self.robot)

    def delayed(self, action: np.ndarray) -> np.ndarray:
        """The action (8,) that acts now: `action` itself, or with latency_steps the one given that many steps ago
        (`action` waits its turn)."""
        if not self.latency_steps:
            return action
        self._late.append(np.asarray(action, np.float64).copy())
        return self._late.popleft()

    def drive(self, action: np.ndarray, fingers: float, each: Callable[[], None] | None = None) -> float:
        """Move the mocap target to the waypoint `action` (8,) (clipped to the workspace; a zero quaternion keeps
        the home orientation), at once or within the robot's limits, and drive the fingers to `fingers` m, for one
        control period of physics, calling `each` after every physics step; returns the physics' seconds."""
        m, d, follower = self.model, self.data, self._follower
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), self.workspace_low, self.workspace_high)
        quat = action[3:7] if np.linalg.norm(action[3:7]) > 1e-6 else HOME_QUAT_XYZW
        if follower is None:
            d.mocap_pos[self._mocap] = action[:3]
            d.mocap_quat[self._mocap] = np.roll(quat, 1) / np.linalg.norm(quat)  # MuJoCo's order: wxyz
        else:
            follower.aim(action[:3], np.roll(quat, 1))
        d.ctrl[self._fingers] = fingers
        start = time.perf_counter()
        for _ in range(round(S.CONTROL_PERIOD_S / m.opt.timestep)):
            if follower is not None:
                follower.step()
                d.mocap_pos[self._mocap], d.mocap_quat[self._mocap] = follower.position, follower.quat
            mujoco.mj_step(m, d)
            if each is not None:
                each()
        return time.perf_counter() - start

    def observe(self, physics_s: float) -> dict:
        """The observation now (module docstring); records the step's timings in `self.timings`."""
        start = time.perf_counter()
        observation = {STATE_KEY: self.ee_state()}
        if self.frames:
            frame = self.camera.frame(self.data)
            if self.robot.pixel_noise:
                frame = noisy_frame(frame, self._pixel_rng, self.robot.pixel_noise)
            observation = {self.image_key: frame, **observation}
        self.timings = {"physics_s": physics_s, "render_s": time.perf_counter() - start}
        return observation

    def render(self) -> np.ndarray | None:
        """The camera's current frame (rgb_array), or None without a render mode."""
        return self.camera.frame(self.data) if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The task's object's position (3,) m and quaternion xyzw (4,)."""
        raise NotImplementedError

    def judge(self, infos: list[dict], **recorded) -> EpisodeResult:
        """An episode's result from `infos` (the reset's, then one per step) and what sim.episode.run_episode
        `recorded` (EpisodeResult's fields)."""
        raise NotImplementedError

    def ee_state(self) -> np.ndarray:
        """observation.state (8,) float32 (module docstring), as the robot senses it, at STATE_RESOLUTION."""
        body = self.data.body(S.GRIPPER_BODY)
        grip = float(np.mean(self.data.qpos[self._finger_qpos]))
        state = np.concatenate([body.xpos, np.roll(body.xquat, -1), [grip]])
        if self.robot.pose_noise_m or self.robot.pose_noise_deg:
            state = noisy_pose(state, self._pose_rng, self.robot)
        return (np.round(state / S.STATE_RESOLUTION) * S.STATE_RESOLUTION).astype(np.float32)

    def touching(self, these: set[int], those: set[int]) -> bool:
        """A contact between a geom of `these` and one of `those` at this physics step (the contacts' geom pairs read
        as one array, not contact by contact: the environments ask after every physics step)."""
        pairs = self.data.contact.geom[: self.data.ncon].tolist()  # [[geom, geom], ...]
        return any((a in these and b in those) or (a in those and b in these) for a, b in pairs)
