"""`TabletopEnv`: what every task's Gymnasium environment shares: the MuJoCo model with the floating gripper welded to
its mocap target (sim.scene.gripper_xml), the fixed camera, LeRobot's observation keys, the action (the next
waypoint) driving the mocap target for one control period, and the state a robot reports.

Observation: `observation.images.<camera>` (height, width, 3) uint8 and `observation.state` (8,) float32,
runtime.spec.STATE_NAMES: the end effector's xyz (m), its quaternion xyzw and the gripper's opening (m, each
finger's travel), at STATE_RESOLUTION. Action (8,) float32 in the same layout, clipped to the workspace.

A task's environment adds `reset`, `step` and two hooks, as Gymnasium's MuJoCo environments add `reset_model`:
`object_pose()` (the task's object, traced through an episode) and `judge(infos, **recorded)` (an episode's result,
sim.episode.run_episode's, from the environment's infos: its task's scoring).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import gymnasium as gym
import mujoco
import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX, STATE_KEY
from cnep.sim import scene as S
from cnep.sim.episode import EpisodeResult
from cnep.sim.render import Camera

HOME_QUAT_XYZW = np.array([0.0, 0.0, 0.0, 1.0])


class TabletopEnv(gym.Env):
    """A tabletop task's environment: `xml` its MJCF (with the gripper of sim.scene), frames (height, width) from
    the camera `camera`, the gripper's opening up to `finger_open` m, `max_steps` control steps an episode."""

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
    ) -> None:
        self.render_mode, self.max_steps = render_mode, max_steps
        self.image_key = IMAGE_KEY_PREFIX + camera
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.camera = Camera(self.model, height, width, camera)
        self.workspace_low = np.array([-S.TABLE_HALF[0], -S.TABLE_HALF[1], 0.03, -1, -1, -1, -1, 0.0], np.float32)
        self.workspace_high = np.array([S.TABLE_HALF[0], S.TABLE_HALF[1], 0.3, 1, 1, 1, 1, finger_open], np.float32)
        self.observation_space = gym.spaces.Dict(
            {
                self.image_key: gym.spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
                STATE_KEY: gym.spaces.Box(-np.inf, np.inf, (len(self.workspace_low),), dtype=np.float32),
            }
        )
        self.action_space = gym.spaces.Box(self.workspace_low, self.workspace_high, dtype=np.float32)
        m = self.model
        gripper = m.body(S.GRIPPER_BODY).id
        self.gripper_geoms = {g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] == gripper}
        self._mocap = m.body(S.MOCAP_BODY).mocapid[0]
        self._fingers = [m.actuator(name).id for name in S.FINGER_JOINTS]
        self._finger_qpos = [m.jnt_qposadr[m.joint(name).id] for name in S.FINGER_JOINTS]
        self.timings = {"physics_s": 0.0, "render_s": 0.0}

    def place_gripper(self, xyz: np.ndarray, opening: float) -> None:
        """Put the gripper (and its mocap target) at `xyz` (m) in the home orientation, its fingers `opening` m."""
        d = self.data
        root = self.model.jnt_qposadr[self.model.body(S.GRIPPER_BODY).jntadr[0]]
        d.qpos[root : root + 3] = xyz
        d.mocap_pos[self._mocap] = xyz
        d.qpos[self._finger_qpos] = opening
        d.ctrl[self._fingers] = opening

    def drive(self, action: np.ndarray, fingers: float, each: Callable[[], None] | None = None) -> float:
        """Move the mocap target to the waypoint `action` (8,) (clipped to the workspace; a zero quaternion keeps
        the home orientation) and drive the fingers to `fingers` m, for one control period of physics, calling
        `each` after every physics step; returns the physics' seconds."""
        m, d = self.model, self.data
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), self.workspace_low, self.workspace_high)
        d.mocap_pos[self._mocap] = action[:3]
        quat = action[3:7] if np.linalg.norm(action[3:7]) > 1e-6 else HOME_QUAT_XYZW
        d.mocap_quat[self._mocap] = np.roll(quat, 1) / np.linalg.norm(quat)  # MuJoCo's order: wxyz
        d.ctrl[self._fingers] = fingers
        start = time.perf_counter()
        for _ in range(round(S.CONTROL_PERIOD_S / m.opt.timestep)):
            mujoco.mj_step(m, d)
            if each is not None:
                each()
        return time.perf_counter() - start

    def observe(self, physics_s: float) -> dict:
        """The observation now (module docstring); records the step's timings in `self.timings`."""
        start = time.perf_counter()
        frame = self.camera.frame(self.data)
        self.timings = {"physics_s": physics_s, "render_s": time.perf_counter() - start}
        return {self.image_key: frame, STATE_KEY: self.ee_state()}

    def render(self) -> np.ndarray | None:
        """The camera's current frame (rgb_array), or None without a render mode."""
        return self.camera.frame(self.data) if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.camera.close()

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The task's object's position (3,) m and quaternion xyzw (4,)."""
        raise NotImplementedError

    def judge(self, infos: list[dict], **recorded) -> EpisodeResult:
        """An episode's result from `infos` (the reset's, then one per step) and what sim.episode.run_episode
        `recorded` (EpisodeResult's fields)."""
        raise NotImplementedError

    def ee_state(self) -> np.ndarray:
        """observation.state (8,) float32 (module docstring), at STATE_RESOLUTION."""
        body = self.data.body(S.GRIPPER_BODY)
        grip = float(np.mean(self.data.qpos[self._finger_qpos]))
        state = np.concatenate([body.xpos, np.roll(body.xquat, -1), [grip]])
        return (np.round(state / S.STATE_RESOLUTION) * S.STATE_RESOLUTION).astype(np.float32)

    def touching(self, these: set[int], those: set[int]) -> bool:
        """A contact between a geom of `these` and one of `those` at this physics step (the contacts' geom pairs read
        as one array, not contact by contact: the environments ask after every physics step)."""
        pairs = self.data.contact.geom[: self.data.ncon].tolist()  # [[geom, geom], ...]
        return any((a in these and b in those) or (a in those and b in these) for a, b in pairs)
