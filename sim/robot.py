"""A robot's constraints on the tabletop's floating gripper: how fast its end effector may move, how noisily it is
sensed, as one settings object every task's environment takes (`RobotSettings`), with a real arm's numbers.

`TELEPORT` is the idealised robot of the v0 environments: the end effector's target jumps to each waypoint, the state
and frames exact. `ARM` is the v1 environments': the target follows the waypoints within a collaborative arm's
Cartesian speed and acceleration (sim.controller), the state carries a pose tracker's noise, and each frame a camera's
sensor noise, the camera's pose and the light drawn anew each episode (sim.noise).
"""

from __future__ import annotations

from dataclasses import dataclass

# A real arm's end-effector limits. A collaborative arm moves its tool at 0.25 m/s and 1.2 m/s² by default (a Universal
# Robots arm's MoveL) and at most at about 1-2 m/s (Franka's Panda: 1.7 m/s, 13 m/s², 2.5 rad/s, 25 rad/s² at the
# flange): the v1 environments' limits lie between, and a UR's rule gives the angular ones (4 x the linear, in rad).
ARM_SPEED = 0.5  # m/s: the target's speed at most
ARM_ACCELERATION = 1.2  # m/s²: the target's acceleration at most (a UR's default tool acceleration)
ARM_ANGULAR_SPEED = 2.0  # rad/s
ARM_ANGULAR_ACCELERATION = 4.8  # rad/s²
ARM_TRACKING_S = 0.05  # s: the time constant with which the target closes the last of its distance to a waypoint
# A real robot's sensing: the pose as a tracker or a calibrated camera-to-robot transform reports it, a webcam's frames.
POSE_NOISE_M = 0.002  # m: standard deviation of the reported position's error, per axis
POSE_NOISE_DEG = 1.0  # degrees: standard deviation of the reported orientation's error, per axis of its rotation
PIXEL_NOISE = 3.0  # standard deviation of each pixel's sensor noise, in levels of 0-255
CAMERA_SHIFT_M = 0.01  # m: the camera stands within this of its mount on each axis, drawn per episode
CAMERA_TURN_DEG = 1.5  # degrees: and looks within this of its mount's direction (about a drawn axis), per episode
LIGHT_JITTER = 0.25  # the light's ambient and diffuse intensity within 1 +- this, drawn per episode


@dataclass(frozen=True)
class RobotSettings:
    """The robot a tabletop environment simulates.

    max_speed: m/s the end effector's target moves at most; None: it jumps to each waypoint (no limit, as the v0
    environments); max_acceleration: m/s²; max_angular_speed: rad/s; max_angular_acceleration: rad/s²; tracking_s:
    the time constant (s) with which the target closes the last of its distance to a waypoint. pose_noise_m: the
    reported position's error, standard deviation per axis (m); pose_noise_deg: the reported orientation's (degrees,
    per axis of its rotation); pixel_noise: each pixel's, in levels of 0-255; camera_shift_m and camera_turn_deg: how
    far the camera stands and looks off its mount, drawn per episode (uniform within); light_jitter: the light's
    intensity within 1 +- this, drawn per episode.
    """

    max_speed: float | None = None
    max_acceleration: float = ARM_ACCELERATION
    max_angular_speed: float = ARM_ANGULAR_SPEED
    max_angular_acceleration: float = ARM_ANGULAR_ACCELERATION
    tracking_s: float = ARM_TRACKING_S
    pose_noise_m: float = 0.0
    pose_noise_deg: float = 0.0
    pixel_noise: float = 0.0
    camera_shift_m: float = 0.0
    camera_turn_deg: float = 0.0
    light_jitter: float = 0.0

    def __post_init__(self) -> None:
        limits = (self.max_acceleration, self.max_angular_speed, self.max_angular_acceleration, self.tracking_s)
        if self.max_speed is not None and not (self.max_speed > 0 and min(limits) > 0):
            raise ValueError(
                f"a robot's speed, acceleration and tracking time must be > 0, got max_speed={self.max_speed}, "
                f"max_acceleration, max_angular_speed, max_angular_acceleration, tracking_s={limits}"
            )
        noise = (self.pose_noise_m, self.pose_noise_deg, self.pixel_noise, self.camera_shift_m, self.camera_turn_deg)
        if min(noise) < 0 or not 0 <= self.light_jitter < 1:
            raise ValueError(
                f"a robot's noise must be >= 0 and its light_jitter in [0, 1), got noise {noise}, "
                f"light_jitter={self.light_jitter}"
            )

    @property
    def randomised(self) -> bool:
        """Whether an episode draws anything for the robot (noise, the camera's pose, the light)."""
        return any(
            (self.pose_noise_m, self.pose_noise_deg, self.pixel_noise, self.camera_shift_m, self.camera_turn_deg,
             self.light_jitter)
        )  # fmt: skip


TELEPORT = RobotSettings()
ARM = RobotSettings(
    max_speed=ARM_SPEED,
    pose_noise_m=POSE_NOISE_M,
    pose_noise_deg=POSE_NOISE_DEG,
    pixel_noise=PIXEL_NOISE,
    camera_shift_m=CAMERA_SHIFT_M,
    camera_turn_deg=CAMERA_TURN_DEG,
    light_jitter=LIGHT_JITTER,
)
