"""The synthetic tabletop scene of the built-in demo: its layout, the K behaviours it calls for, and its camera frames.

A top-down camera looks at a table (world x: lateral, y: away from the robot, z: up; metres). On the
table stand a red cup on a yellow mat, either on the left or on the right, and a two-slot tray whose
near or far slot is already taken by a blue block. The demonstrator grasps the cup and puts it into the
free slot, so the scene decides which of the K = 4 behaviours it performs, as in the paper's wine-glass
task (where the glass stands x where it goes):

    behaviour 0 left-near   cup on the left,  near slot free
    behaviour 1 left-far    cup on the left,  far slot free
    behaviour 2 right-near  cup on the right, near slot free
    behaviour 3 right-far   cup on the right, far slot free

A free-choice scene (`FREE_CHOICE`) has no block: both slots are free, both places are right, and the
demonstrator picks one at random; `Scene.behaviour` is then the behaviour performed, which the scene
does not decide (the frames show it only once the cup is carried towards the chosen slot).

Frames also show clutter (small random shapes), lighting changes (gain, a brightness gradient, sensor
noise) and position noise of every object, and the gripper seen from above (its fingers open and close).
The mat stays where the cup stood and the block stays in its slot, so the behaviour stays visible in
every frame of an episode.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# Frame size: small, the extractor resizes to 224 x 224 anyway and JPEG decoding is part of the budget.
FRAME_WIDTH = 160
FRAME_HEIGHT = 120
# The table is drawn top-down on a canvas, then seen by a camera at the robot's front right that looks
# obliquely across the table (a homography): what stands nearer the camera looks bigger. The MobileNet
# features are globally average-pooled, so they keep what is in the frame and how much of it, far
# more than where it is; perspective turns "where" into "how big" (measured with the random-weight extractor).
CANVAS_WIDTH = 320
CANVAS_HEIGHT = 240
# Frame pixels of the canvas corners top-left (far left), top-right, bottom-right (near right), bottom-left.
CAMERA_CORNERS = ((40.0, 8.0), (130.0, 0.0), (200.0, 160.0), (-30.0, 115.0))
FLOOR_RGB = (70, 70, 75)  # outside the table

# Visible table area (m): x in [-TABLE_HALF_WIDTH, TABLE_HALF_WIDTH], y in [TABLE_NEAR, TABLE_FAR].
TABLE_HALF_WIDTH = 0.40
TABLE_NEAR = 0.30
TABLE_FAR = 0.90

BEHAVIOURS = ("left-near", "left-far", "right-near", "right-far")
SIDES = ("left", "right")
FREE_CHOICE = tuple(f"{side}-either" for side in SIDES)  # scenes with both slots free
CUP_XY = {"left": (-0.22, 0.62), "right": (0.22, 0.62)}  # nominal cup positions (m)
SLOT_XY = {"near": (0.10, 0.47), "far": (-0.10, 0.80)}  # nominal slot centres (m); tray = both slots
POSITION_NOISE = 0.015  # std of the cup's and clutter's offset from its nominal position (m)
TRAY_NOISE = 0.005  # std of the tray's offset (m): it is furniture, it barely moves
CUP_RADIUS = 0.045  # m
MAT_HALF = 0.065  # half side of the mat under the cup (m)
SLOT_HALF = 0.06  # half side of a slot (m)
BLOCK_HALF = 0.045  # half side of the blue block (m)
CLUTTER_COUNT = (2, 6)  # clutter items per scene: [low, high)
CLUTTER_RADIUS = (0.008, 0.018)  # m
GAIN_RANGE = (0.85, 1.15)  # overall lighting gain
GRADIENT_MAX = 15.0  # grey levels of the brightness gradient across the frame, at most
SENSOR_NOISE = 2.0  # std of the sensor noise (grey levels)
NOISE_CELL = 4  # the noise is drawn on cells of this many pixels and interpolated (spatially correlated)
BLUR_SIGMA = 1.0  # lens blur (frame pixels)
JPEG_QUALITY = 85

# Colours (RGB).
TABLE_RGB = (150, 115, 80)
TRAY_RGB = (105, 105, 110)
SLOT_RGB = (60, 60, 65)
CUP_RGB = (220, 40, 35)
MAT_RGB = (235, 205, 60)
BLOCK_RGB = (40, 70, 220)
GRIPPER_RGB = (30, 30, 30)
CLUTTER_RGB = ((90, 160, 90), (160, 90, 170), (200, 200, 200), (70, 140, 150))


def behaviour_parts(behaviour: int) -> tuple[str, str]:
    """(cup side, free slot) of behaviour index 0..3, e.g. 1 -> ("left", "far")."""
    if not 0 <= behaviour < len(BEHAVIOURS):
        raise ValueError(f"behaviour must be in 0..{len(BEHAVIOURS) - 1}, got {behaviour}")
    side, slot = BEHAVIOURS[behaviour].split("-")
    return side, slot


@dataclass(frozen=True)
class Scene:
    """One table set-up (positions in m) and its lighting.

    behaviour: what the demonstrator does here; the scene decides it (the block takes the other slot)
    unless `both_free` (no block: the demonstrator chose it).
    """

    behaviour: int
    cup_xy: np.ndarray  # (2,)
    slot_xy: dict[str, np.ndarray]  # "near"/"far" -> (2,) slot centre
    clutter: tuple[tuple[float, float, float, int], ...]  # (x, y, radius, colour index)
    gain: float
    gradient: np.ndarray  # (2,) grey levels per frame width along u and v
    both_free: bool = False

    @property
    def free_slot(self) -> str:
        """The slot the cup goes into (with both slots free: the one the demonstrator chose)."""
        return behaviour_parts(self.behaviour)[1]

    @property
    def taken_slot(self) -> str | None:
        """The slot the block takes; None when both are free."""
        if self.both_free:
            return None
        return "far" if self.free_slot == "near" else "near"


def sample_scene(behaviour: int, rng: np.random.Generator, both_free: bool = False) -> Scene:
    """A random table set-up for `behaviour` (position noise, clutter, lighting); `both_free`: no block."""
    side, _ = behaviour_parts(behaviour)
    cup = np.asarray(CUP_XY[side]) + rng.normal(0.0, POSITION_NOISE, 2)
    tray_offset = rng.normal(0.0, TRAY_NOISE, 2)  # the tray moves as one piece
    slots = {name: np.asarray(xy) + tray_offset for name, xy in SLOT_XY.items()}
    clutter = []
    for _ in range(int(rng.integers(*CLUTTER_COUNT))):
        x = rng.uniform(-TABLE_HALF_WIDTH, TABLE_HALF_WIDTH)
        y = rng.uniform(TABLE_NEAR, TABLE_FAR)
        clutter.append((x, y, rng.uniform(*CLUTTER_RADIUS), int(rng.integers(len(CLUTTER_RGB)))))
    return Scene(
        behaviour,
        cup,
        slots,
        tuple(clutter),
        float(rng.uniform(*GAIN_RANGE)),
        rng.uniform(-GRADIENT_MAX, GRADIENT_MAX, 2),
        both_free,
    )


def to_pixels(xy: np.ndarray) -> tuple[int, int]:
    """World (x, y) in m -> canvas pixel (u, v) of the top-down drawing; the robot is at the bottom edge."""
    u = (xy[0] + TABLE_HALF_WIDTH) / (2 * TABLE_HALF_WIDTH) * CANVAS_WIDTH
    v = CANVAS_HEIGHT - (xy[1] - TABLE_NEAR) / (TABLE_FAR - TABLE_NEAR) * CANVAS_HEIGHT
    return int(round(u)), int(round(v))


def metres_to_pixels(length: float) -> int:
    """A length on the table (m) -> canvas pixels."""
    return max(1, int(round(length / (2 * TABLE_HALF_WIDTH) * CANVAS_WIDTH)))


def camera_homography() -> np.ndarray:
    """(3, 3) homography from canvas pixels to camera-frame pixels."""
    canvas = np.float32([[0, 0], [CANVAS_WIDTH, 0], [CANVAS_WIDTH, CANVAS_HEIGHT], [0, CANVAS_HEIGHT]])
    return cv2.getPerspectiveTransform(canvas, np.float32(CAMERA_CORNERS))


def _square(img: np.ndarray, xy: np.ndarray, half: float, rgb: tuple[int, int, int], thickness: int = -1) -> None:
    u, v = to_pixels(xy)
    h = metres_to_pixels(half)
    cv2.rectangle(img, (u - h, v - h), (u + h, v + h), rgb, thickness, cv2.LINE_AA)


def _gripper(img: np.ndarray, pose: np.ndarray, opening: float) -> None:
    """Two fingers around the end-effector, rotated by its yaw, apart by `opening` (0 closed .. 1 open)."""
    u, v = to_pixels(pose[:2])
    yaw = yaw_of(pose[3:7])
    scale = 1.0 + 1.5 * float(pose[2])  # nearer the camera (higher z) looks bigger
    half_gap = metres_to_pixels(0.02 + 0.035 * opening) * scale
    length = metres_to_pixels(0.05) * scale
    across = np.array([np.cos(yaw), -np.sin(yaw)])  # finger separation direction in pixels
    along = np.array([np.sin(yaw), np.cos(yaw)])
    for sign in (-1.0, 1.0):
        centre = np.array([u, v]) + sign * half_gap * across
        a, b = centre - 0.5 * length * along, centre + 0.5 * length * along
        cv2.line(
            img,
            tuple(int(c) for c in a),
            tuple(int(c) for c in b),
            GRIPPER_RGB,
            metres_to_pixels(0.012 * scale),
            cv2.LINE_AA,
        )
    cv2.line(img, (u, v), (u, CANVAS_HEIGHT), GRIPPER_RGB, metres_to_pixels(0.02 * scale), cv2.LINE_AA)  # the arm


def gripper_quaternion(yaw: float) -> np.ndarray:
    """Quaternion xyzw (4,) of a gripper pointing straight down, turned by `yaw` (rad) about the vertical.

    q = q_yaw(z) * q_down, with q_down the half turn about x: (cos(yaw/2), sin(yaw/2), 0, 0).
    """
    return np.array([np.cos(yaw / 2), np.sin(yaw / 2), 0.0, 0.0])


def yaw_of(quat_xyzw: np.ndarray) -> float:
    """The yaw (rad) of a downward gripper quaternion made by `gripper_quaternion` (q and -q agree)."""
    return float(2.0 * np.arctan2(quat_xyzw[1], quat_xyzw[0]))


def draw_frame(
    scene: Scene, pose: np.ndarray, opening: float, cup_xy: np.ndarray | None, rng: np.random.Generator
) -> np.ndarray:
    """The camera frame (FRAME_HEIGHT, FRAME_WIDTH, 3) uint8 RGB of `scene` with the gripper at `pose` (7,).

    opening: gripper opening, 0 closed .. 1 open; cup_xy: where the cup stands (2,), or None while it is
    held (then it is drawn between the fingers); rng draws the sensor noise.
    """
    img = np.empty((CANVAS_HEIGHT, CANVAS_WIDTH, 3), dtype=np.uint8)
    img[:] = TABLE_RGB
    near, far = scene.slot_xy["near"], scene.slot_xy["far"]
    centre, half = (near + far) / 2, np.abs(far - near) / 2 + SLOT_HALF + 0.015
    u0, v0 = to_pixels(centre - half * np.array([1, -1]))
    u1, v1 = to_pixels(centre + half * np.array([1, -1]))
    cv2.rectangle(img, (u0, v0), (u1, v1), TRAY_RGB, -1, cv2.LINE_AA)
    for xy in scene.slot_xy.values():
        _square(img, xy, SLOT_HALF, SLOT_RGB)
    if scene.taken_slot is not None:
        _square(img, scene.slot_xy[scene.taken_slot], BLOCK_HALF, BLOCK_RGB)
    _square(img, scene.cup_xy, MAT_HALF, MAT_RGB)
    for x, y, radius, colour in scene.clutter:
        cv2.circle(img, to_pixels(np.array([x, y])), metres_to_pixels(radius), CLUTTER_RGB[colour], -1, cv2.LINE_AA)
    cup_at = pose[:2] if cup_xy is None else cup_xy
    cv2.circle(img, to_pixels(cup_at), metres_to_pixels(CUP_RADIUS), CUP_RGB, -1, cv2.LINE_AA)
    _gripper(img, pose, opening)
    frame = cv2.warpPerspective(
        img,
        camera_homography(),
        (FRAME_WIDTH, FRAME_HEIGHT),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=FLOOR_RGB,
    )
    return _light(frame, scene, rng)


def _light(img: np.ndarray, scene: Scene, rng: np.random.Generator) -> np.ndarray:
    """Lens blur, lighting gain, a linear brightness gradient and sensor noise (smooth, as after demosaicing)."""
    img = cv2.GaussianBlur(img, (0, 0), BLUR_SIGMA)
    u = np.linspace(-0.5, 0.5, FRAME_WIDTH)[None, :, None]
    v = np.linspace(-0.5, 0.5, FRAME_HEIGHT)[:, None, None]
    shade = scene.gradient[0] * u + scene.gradient[1] * v  # (H, W, 1)
    coarse = rng.normal(0.0, SENSOR_NOISE, (FRAME_HEIGHT // NOISE_CELL, FRAME_WIDTH // NOISE_CELL, 3))
    noise = cv2.resize(coarse, (FRAME_WIDTH, FRAME_HEIGHT), interpolation=cv2.INTER_LINEAR)  # (H, W, 3)
    noisy = img.astype(np.float32) * scene.gain + shade + noise
    return np.clip(noisy, 0, 255).astype(np.uint8)


def encode_jpeg(rgb: np.ndarray) -> bytes:
    """(H, W, 3) uint8 RGB -> JPEG bytes."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # cannot happen for a uint8 3-channel image; kept as a clear error rather than an empty frame
        raise RuntimeError("OpenCV failed to encode a frame as JPEG")
    return buf.tobytes()
