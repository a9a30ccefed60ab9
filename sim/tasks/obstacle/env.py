"""`ObstacleEnv`: the obstacle task as a Gymnasium environment (`gymnasium.make("cnep/Obstacle-v0")`, or
`"cnep/Obstacle-v1"`: a robot's constraints, the box and the goal moved, sim.tasks.obstacle.versions).

Observation (LeRobot's keys): `observation.images.front` the camera frame (IMAGE_HEIGHT, IMAGE_WIDTH, 3) uint8, and
`observation.state` (8,) float32, runtime.spec.STATE_NAMES: the end effector's xyz (m), its quaternion xyzw and the
gripper's opening (m, each finger's travel), at STATE_RESOLUTION as a robot reports them. Action (8,) float32: the
next waypoint in the same layout; the mocap target moves there and the gripper body follows through the soft weld
for CONTROL_PERIOD_S of physics, the fingers driven to the gripper value.

An episode starts at a start drawn from the seed (`reset(seed=)`), the box at the origin and the goal fixed (v0),
or both drawn (v1: `env.scene`). It ends (`terminated`) when the end effector comes within GOAL_TOLERANCE of the
goal, else is truncated after `max_steps`. `info` per step: `is_success` (at the goal and the box never touched),
`collision` (a contact between the gripper and the box so far, read from the physics' contacts), `clearance` (m, the
smallest gripper-box distance so far), `distance_to_goal` (m, xy); `env.timings` holds the last step's `physics_s`
and `render_s` (seconds its physics and rendering took; kept out of `info`, which the same seed and actions reproduce
exactly). With `cue=True` a tile on one side (drawn from the seed, `info["cue_side"]`) says where to pass: from the
start (v0), or from the step `info["cue_step"]` on (v1: once the gripper has moved a drawn distance towards the goal,
or at the version's latest step; None until then; the cue shows before that step's action acts).

`version` (0 or 1) chooses the robot and the scenes (sim.tasks.obstacle.versions); `latency_steps` and `frames` are
sim.tabletop's.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX
from cnep.sim import scene as S
from cnep.sim.paths import yaw_quaternion
from cnep.sim.tabletop import TabletopEnv
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.scoring import ObstacleEpisode, judge
from cnep.sim.tasks.obstacle.versions import version_of

SIDES = O.SIDES
IMAGE_KEY = IMAGE_KEY_PREFIX + O.CAMERA


class ObstacleEnv(TabletopEnv):
    """Start to goal past a box on a tabletop, seen by a fixed camera (module docstring); `cue`: the variant where a
    tile shows the side to pass; `max_steps` None: the version's."""

    def __init__(
        self,
        cue: bool = False,
        render_mode: str | None = None,
        max_steps: int | None = None,
        version: int = 0,
        latency_steps: int = 0,
        frames: bool = True,
    ) -> None:
        self.version = version_of(version)
        super().__init__(
            O.scene_xml(),
            height=O.IMAGE_HEIGHT,
            width=O.IMAGE_WIDTH,
            camera=O.CAMERA,
            finger_open=S.FINGER_OPEN,
            max_steps=self.version.max_steps if max_steps is None else max_steps,
            render_mode=render_mode,
            robot=self.version.robot,
            latency_steps=latency_steps,
            frames=frames,
        )
        self.cue = cue
        self._box_geom = self.model.geom(O.BOX_GEOM).id
        self.cue_side: str | None = None
        self.scene: dict = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """A new episode. options: `start` (x, y) in m instead of the drawn start; `cue_side` ("left" or "right")
        instead of the drawn side (the cue variant)."""
        super().reset(seed=seed)
        options, v = options or {}, self.version
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        jitter = self.np_random.uniform(-v.start_jitter, v.start_jitter, 2)
        start = np.asarray(options.get("start", (v.start[0] + jitter[0], v.start[1] + jitter[1])), dtype=np.float64)
        side = options.get("cue_side", SIDES[int(self.np_random.integers(2))])
        self.cue_side = side if self.cue else None
        self.scene = {"start": start, "box_xy": np.zeros(2), "box_yaw": 0.0, "goal_xy": np.asarray(v.goal)}
        if v.cue_after is None:
            cue_pos = (O.SIDE_SIGN[side] * O.CUE_XY[0], O.CUE_XY[1], 0.001) if self.cue else (0.0, 0.0, -0.5)
            m.geom_pos[m.geom(O.CUE_GEOM).id] = cue_pos
            self._cue_step = 0 if self.cue else None
        else:
            self._draw_scene(side)
        self.place_gripper((*start, O.EE_HEIGHT), S.FINGER_OPEN)
        mujoco.mj_forward(m, d)
        self._steps, self._collision, self._clearance = 0, False, self._distance_to_box()
        observation = self.observe(0.0)
        return observation, {**self._info(), "start": start.copy()}

    def _draw_scene(self, side: str) -> None:
        """The box's pose, the goal and when the cue shows (v1), drawn into `self.scene`; the cue hidden."""
        m, v, rng = self.model, self.version, self.np_random
        box_xy = rng.uniform(-v.box_jitter, v.box_jitter, 2)
        box_yaw = float(rng.uniform(-v.box_yaw_deg, v.box_yaw_deg))
        goal_xy = np.asarray(v.goal) + rng.uniform(-v.goal_jitter, v.goal_jitter, 2)
        cue_after = float(rng.uniform(*v.cue_after))
        self.scene.update(box_xy=box_xy, box_yaw=box_yaw, goal_xy=goal_xy, cue_after=cue_after)
        root = m.jnt_qposadr[m.body(O.BOX_BODY).jntadr[0]]
        self.data.qpos[root : root + 3] = (*box_xy, O.BOX_HALF[2])
        self.data.qpos[root + 3 : root + 7] = np.roll(yaw_quaternion(box_yaw), 1)
        m.geom_pos[m.geom("goal").id] = (*goal_xy, 0.001)
        m.geom_pos[m.geom(O.CUE_GEOM).id] = (0.0, 0.0, -0.5)
        self._cue_step = None

    def _cue_shows_now(self) -> bool:
        """Whether the cue (v1, the cue variant, not shown yet) shows before this step acts: the gripper has moved the
        drawn distance towards the goal, or this is the version's latest step."""
        if not self.cue or self._cue_step is not None:
            return False
        moved = self.data.body(S.GRIPPER_BODY).xpos[1] - self.scene["start"][1]
        return moved >= self.scene["cue_after"] or self._steps >= self.version.cue_latest_step

    def _show_cue(self) -> None:
        box_x, box_y = self.scene["box_xy"]
        cue = (box_x + O.SIDE_SIGN[self.cue_side] * O.CUE_XY[0], box_y + O.CUE_XY[1], 0.001)
        self.model.geom_pos[self.model.geom(O.CUE_GEOM).id] = cue
        self._cue_step = self._steps

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Move towards the waypoint `action` (8,) for one control period; (observation, reward, terminated,
        truncated, info), reward 1 at the step that succeeds."""
        action = self.delayed(np.asarray(action, dtype=np.float64).reshape(-1))
        if self._cue_shows_now():
            self._show_cue()
        physics_s = self.drive(action, action[7], self._note_contact)
        self._clearance = min(self._clearance, self._distance_to_box())
        self._steps += 1
        observation = self.observe(physics_s)
        info = self._info()
        terminated = info["distance_to_goal"] < O.GOAL_TOLERANCE
        truncated = not terminated and self._steps >= self.max_steps
        return observation, float(info["is_success"]), terminated, truncated, info

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The box's position (3,) m and quaternion xyzw (4,)."""
        body = self.data.body(O.BOX_BODY)
        return body.xpos.copy(), np.roll(body.xquat, -1)

    def judge(self, infos: list[dict], **recorded) -> ObstacleEpisode:
        """The episode's result (sim.tasks.obstacle.scoring.judge)."""
        return judge(infos, **recorded)

    def _info(self) -> dict:
        to_goal = float(np.linalg.norm(self.data.body(S.GRIPPER_BODY).xpos[:2] - self.scene["goal_xy"]))
        return {
            "is_success": bool(to_goal < O.GOAL_TOLERANCE and not self._collision),
            "collision": self._collision,
            "clearance": float(self._clearance),
            "distance_to_goal": to_goal,
            "cue_side": self.cue_side,
            "cue_step": self._cue_step,
        }

    def _note_contact(self) -> None:
        """After a physics step: a contact between a gripper geom and the box makes the episode a collision."""
        self._collision = self._collision or self.touching(self.gripper_geoms, {self._box_geom})

    def _distance_to_box(self) -> float:
        """The smallest distance (m) between a gripper geom and the box (negative: penetrating)."""
        fromto = np.zeros(6)
        return min(
            mujoco.mj_geomDistance(self.model, self.data, g, self._box_geom, 1.0, fromto) for g in self.gripper_geoms
        )
