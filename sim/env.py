"""`ObstacleEnv`: the obstacle task as a Gymnasium environment (`gymnasium.make("cnep/Obstacle-v0")`).

Observation (LeRobot's keys): `observation.images.front` the camera frame (IMAGE_HEIGHT, IMAGE_WIDTH, 3) uint8, and
`observation.state` (8,) float32, runtime.spec.STATE_NAMES: the end effector's xyz (m), its quaternion xyzw and the
gripper's opening (m, each finger's travel), at STATE_RESOLUTION as a robot reports them. Action (8,) float32: the
next waypoint in the same layout; the mocap target moves there and the gripper body follows through the soft weld
for CONTROL_PERIOD_S of physics, the fingers driven to the gripper value.

An episode starts at a start drawn from the seed (`reset(seed=)`), the box at the origin, the goal fixed. It ends
(`terminated`) when the end effector comes within GOAL_TOLERANCE of the goal, else is truncated after MAX_STEPS.
`info` per step: `is_success` (at the goal and the box never touched), `collision` (a contact between the gripper
and the box so far, read from the physics' contacts), `clearance` (m, the smallest gripper-box distance so far),
`distance_to_goal` (m, xy); `env.timings` holds the last step's `physics_s` and `render_s` (seconds its physics and
rendering took; kept out of `info`, which the same seed and actions reproduce exactly).
With `cue=True` a tile on one side (drawn from the seed, `info["cue_side"]`) says where to pass.
"""

from __future__ import annotations

import time

import gymnasium as gym
import mujoco
import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX, STATE_KEY
from cnep.sim import scene as S
from cnep.sim.demonstrator import SIDE_SIGN
from cnep.sim.render import Camera

SIDES = tuple(SIDE_SIGN)
IMAGE_KEY = IMAGE_KEY_PREFIX + S.CAMERA
HOME_QUAT_XYZW = np.array([0.0, 0.0, 0.0, 1.0])
WORKSPACE_LOW = np.array([-S.TABLE_HALF[0], -S.TABLE_HALF[1], 0.03, -1, -1, -1, -1, 0.0], dtype=np.float32)
WORKSPACE_HIGH = np.array([S.TABLE_HALF[0], S.TABLE_HALF[1], 0.3, 1, 1, 1, 1, S.FINGER_OPEN], dtype=np.float32)


class ObstacleEnv(gym.Env):
    """Start to goal past a box on a tabletop, seen by a fixed camera (module docstring); `cue`: the variant where a
    tile shows the side to pass."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": round(1 / S.CONTROL_PERIOD_S)}

    def __init__(self, cue: bool = False, render_mode: str | None = None, max_steps: int = S.MAX_STEPS) -> None:
        self.cue, self.render_mode, self.max_steps = cue, render_mode, max_steps
        self.model = mujoco.MjModel.from_xml_string(S.scene_xml())
        self.data = mujoco.MjData(self.model)
        self.camera = Camera(self.model)
        self.observation_space = gym.spaces.Dict(
            {
                IMAGE_KEY: gym.spaces.Box(0, 255, (S.IMAGE_HEIGHT, S.IMAGE_WIDTH, 3), dtype=np.uint8),
                STATE_KEY: gym.spaces.Box(-np.inf, np.inf, (len(WORKSPACE_LOW),), dtype=np.float32),
            }
        )
        self.action_space = gym.spaces.Box(WORKSPACE_LOW, WORKSPACE_HIGH, dtype=np.float32)
        m = self.model
        self._gripper_geoms = {
            g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] == m.body(S.GRIPPER_BODY).id
        }
        self._box_geom = m.geom(S.BOX_GEOM).id
        self._mocap = m.body(S.MOCAP_BODY).mocapid[0]
        self._fingers = [m.actuator(name).id for name in S.FINGER_JOINTS]
        self._finger_qpos = [m.jnt_qposadr[m.joint(name).id] for name in S.FINGER_JOINTS]
        self.cue_side: str | None = None
        self.timings = {"physics_s": 0.0, "render_s": 0.0}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """A new episode. options: `start` (x, y) in m instead of the drawn start; `cue_side` ("left" or "right")
        instead of the drawn side (the cue variant)."""
        super().reset(seed=seed)
        options = options or {}
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        jitter = self.np_random.uniform(-S.START_JITTER, S.START_JITTER, 2)
        start = np.asarray(options.get("start", (jitter[0], S.START_Y + jitter[1])), dtype=np.float64)
        side = options.get("cue_side", SIDES[int(self.np_random.integers(2))])
        self.cue_side = side if self.cue else None
        cue_pos = (SIDE_SIGN[side] * S.CUE_XY[0], S.CUE_XY[1], 0.001) if self.cue else (0.0, 0.0, -0.5)
        m.geom_pos[m.geom(S.CUE_GEOM).id] = cue_pos
        root = m.jnt_qposadr[m.body(S.GRIPPER_BODY).jntadr[0]]
        d.qpos[root : root + 3] = (*start, S.EE_HEIGHT)
        d.mocap_pos[self._mocap] = (*start, S.EE_HEIGHT)
        d.qpos[self._finger_qpos] = S.FINGER_OPEN
        d.ctrl[self._fingers] = S.FINGER_OPEN
        mujoco.mj_forward(m, d)
        self._steps, self._collision, self._clearance = 0, False, self._distance_to_box()
        observation = self._observe(0.0)
        return observation, {**self._info(), "start": start.copy()}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Move towards the waypoint `action` (8,) for one control period; (observation, reward, terminated,
        truncated, info), reward 1 at the step that succeeds."""
        m, d = self.model, self.data
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), WORKSPACE_LOW, WORKSPACE_HIGH)
        d.mocap_pos[self._mocap] = action[:3]
        quat = action[3:7] if np.linalg.norm(action[3:7]) > 1e-6 else HOME_QUAT_XYZW
        d.mocap_quat[self._mocap] = np.roll(quat, 1) / np.linalg.norm(quat)  # MuJoCo's order: wxyz
        d.ctrl[self._fingers] = action[7]
        start = time.perf_counter()
        for _ in range(round(S.CONTROL_PERIOD_S / m.opt.timestep)):
            mujoco.mj_step(m, d)
            self._collision = self._collision or self._touching()
        self._clearance = min(self._clearance, self._distance_to_box())
        physics_s = time.perf_counter() - start
        self._steps += 1
        observation = self._observe(physics_s)
        info = self._info()
        terminated = info["distance_to_goal"] < S.GOAL_TOLERANCE
        truncated = not terminated and self._steps >= self.max_steps
        return observation, float(info["is_success"]), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """The camera's current frame (rgb_array), or None without a render mode."""
        return self.camera.frame(self.data) if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.camera.close()

    def ee_state(self) -> np.ndarray:
        """observation.state (8,) float32 (module docstring), at STATE_RESOLUTION."""
        body = self.data.body(S.GRIPPER_BODY)
        grip = float(np.mean(self.data.qpos[self._finger_qpos]))
        state = np.concatenate([body.xpos, np.roll(body.xquat, -1), [grip]])
        return (np.round(state / S.STATE_RESOLUTION) * S.STATE_RESOLUTION).astype(np.float32)

    def box_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The box's position (3,) m and quaternion xyzw (4,)."""
        body = self.data.body(S.BOX_BODY)
        return body.xpos.copy(), np.roll(body.xquat, -1)

    def _observe(self, physics_s: float) -> dict:
        start = time.perf_counter()
        frame = self.camera.frame(self.data)
        self.timings = {"physics_s": physics_s, "render_s": time.perf_counter() - start}
        return {IMAGE_KEY: frame, STATE_KEY: self.ee_state()}

    def _info(self) -> dict:
        to_goal = float(np.linalg.norm(self.data.body(S.GRIPPER_BODY).xpos[:2] - np.asarray(S.GOAL_XY)))
        return {
            "is_success": bool(to_goal < S.GOAL_TOLERANCE and not self._collision),
            "collision": self._collision,
            "clearance": float(self._clearance),
            "distance_to_goal": to_goal,
            "cue_side": self.cue_side,
        }

    def _touching(self) -> bool:
        """A contact between a gripper geom and the box at this physics step."""
        for contact in self.data.contact[: self.data.ncon]:
            pair = {int(contact.geom1), int(contact.geom2)}
            if self._box_geom in pair and pair & self._gripper_geoms:
                return True
        return False

    def _distance_to_box(self) -> float:
        """The smallest distance (m) between a gripper geom and the box (negative: penetrating)."""
        fromto = np.zeros(6)
        return min(
            mujoco.mj_geomDistance(self.model, self.data, g, self._box_geom, 1.0, fromto) for g in self._gripper_geoms
        )
