"""What a real robot's sensing adds to the tabletop's observations (sim.robot.RobotSettings): noise on the reported
pose, a camera's sensor noise on each frame, and per episode the camera's pose off its mount and the light's
intensity. Every draw comes from the generator it is handed, so a seeded episode is reproduced exactly.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from cnep.sim.controller import turned
from cnep.sim.robot import RobotSettings


def noisy_pose(state: np.ndarray, rng: np.random.Generator, robot: RobotSettings) -> np.ndarray:
    """`state` (8,): xyz (m), quaternion xyzw, gripper; its position and orientation with a tracker's error drawn from
    `rng` (robot.pose_noise_m per axis; a turn of robot.pose_noise_deg per axis), a new array."""
    noisy = np.array(state, np.float64)
    noisy[:3] += rng.normal(0.0, robot.pose_noise_m, 3)
    error = rng.normal(0.0, math.radians(robot.pose_noise_deg), 3)
    noisy[3:7] = np.roll(turned(np.roll(noisy[3:7], 1), error), -1)  # MuJoCo's order: wxyz
    return noisy


def noisy_frame(frame: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    """`frame` (H, W, 3) uint8 with Gaussian sensor noise of `sigma` levels per pixel and channel, a new array."""
    noisy = rng.standard_normal(frame.shape, dtype=np.float32)  # float32 in place: a frame a control step
    noisy *= sigma
    noisy += frame
    np.rint(noisy, out=noisy)
    np.clip(noisy, 0, 255, out=noisy)
    return noisy.astype(np.uint8)


class CameraDraw:
    """A scene's camera `name` and light as built, and each episode's pose and light drawn around them (`draw`)."""

    def __init__(self, model: mujoco.MjModel, name: str) -> None:
        self.model, self.id = model, model.camera(name).id
        self.pos, self.quat = model.cam_pos[self.id].copy(), model.cam_quat[self.id].copy()
        self.ambient = model.vis.headlight.ambient.copy()
        self.diffuse = model.vis.headlight.diffuse.copy()

    def draw(self, rng: np.random.Generator, robot: RobotSettings) -> None:
        """The camera moved within robot.camera_shift_m on each axis and turned within robot.camera_turn_deg (about a
        drawn axis), the light's intensity scaled within 1 +- robot.light_jitter, all drawn from `rng`."""
        m = self.model
        m.cam_pos[self.id] = self.pos + rng.uniform(-robot.camera_shift_m, robot.camera_shift_m, 3)
        axis = rng.normal(size=3)
        angle = math.radians(rng.uniform(-robot.camera_turn_deg, robot.camera_turn_deg))
        m.cam_quat[self.id] = turned(self.quat, axis / np.linalg.norm(axis) * angle)
        scale = 1.0 + rng.uniform(-robot.light_jitter, robot.light_jitter)
        m.vis.headlight.ambient = np.clip(self.ambient * scale, 0.0, 1.0)
        m.vis.headlight.diffuse = np.clip(self.diffuse * scale, 0.0, 1.0)
