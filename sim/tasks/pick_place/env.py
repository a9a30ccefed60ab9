"""`PickPlaceEnv`: the pick-and-place task as a Gymnasium environment (`gymnasium.make("cnep/PickPlace-v0")`, or
`"cnep/PickPlace-v1"`: a robot's constraints and a change during the carry, sim.tasks.pick_place.versions).

Observation and action as every tabletop task's (sim.tabletop), the camera `observation.images.overhead`. The
action's gripper is a two-state gripper's command: below CLOSE_BELOW the fingers close (driven to 0, so they
squeeze what they hold), else they open to FINGER_OPEN; the state reports the fingers' opening as measured.

An episode (`reset(seed=)`) draws the gripper's start, the bar's pose and orientation (which decides the grasp and
so its two places), the places the `condition` takes (its scene's CONDITIONS: `decided`, `free`, `changed`; or
`mixed`: decided or free with equal chance, the demonstrations' scenes) and, for `changed`, when the cup moves to the
grasp's other place: v0 at a drawn step (before the grasp closes); v1 during the carry, once the bar is lifted and
the gripper has covered a drawn share of the way from where it lifted the bar to the valid place (a policy heading
elsewhere never changes it). It ends (`terminated`) once the bar was lifted and rests, released, on the
table (on a mat or not), else is truncated after `max_steps`. Judged by the physics (`info`): `lifted` (the bar
rose LIFTED_Z), `dropped` (out of the fingers with its bottom DROP_HEIGHT above the table), `collision` (the
gripper or the bar touched a cup), `place` (the mat whose footprint holds the bar's whole footprint at the end,
or None), `valid` (the places free now that fit the bar's orientation), `is_success` (lifted, not dropped, no
collision, at rest in a valid place, released); the change: `change_step` (v0: the step drawn; v1: the step at which
the cup moved, None until it does: the table changes before that step's action acts) and `valid_after_change` (the
valid places right after it, None before); the grasp: `grasp_offset_m` (how far the gripper was from the bar's centre,
horizontally, when it was first commanded to close; None before). `env.timings` holds the last step's physics and
render seconds.

`version` (0 or 1) chooses the robot and the scenes (sim.tasks.pick_place.versions); `latency_steps` and `frames`
are sim.tabletop's.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX
from cnep.sim import scene as S
from cnep.sim.paths import yaw_quaternion
from cnep.sim.tabletop import TabletopEnv
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.layout import CUPS, TILE_BODY, PickLayout, cup_body
from cnep.sim.tasks.pick_place.scoring import PickEpisode, judge
from cnep.sim.tasks.pick_place.versions import IN_CARRY, PickPlaceVersion, version_of

MIXED = "mixed"
PICK_IMAGE_KEY = IMAGE_KEY_PREFIX + P.CAMERA
FOOTPRINT_TOLERANCE = 0.005  # m: how far the bar's corners may lie outside a mat's edge


def grasp_places(orientation: str) -> tuple[int, ...]:
    """The places (indices of PLACES) a bar lying `orientation` fits."""
    return P.BAR.grasp_places(orientation)


class PickPlaceEnv(TabletopEnv):
    """Pick the bar and put it on a free mat it fits (module docstring); `condition`: the scenes drawn; `max_steps`
    None: the version's; `layout`: the scene (sim.tasks.pick_place.layout; the bar's, P.BAR, unless another task's);
    `version`: a number or the version itself (another task's settings of a version)."""

    def __init__(
        self,
        condition: str = MIXED,
        render_mode: str | None = None,
        max_steps: int | None = None,
        version: int | PickPlaceVersion = 0,
        latency_steps: int = 0,
        frames: bool = True,
        layout: PickLayout = P.BAR,
    ) -> None:
        if condition not in (MIXED, *P.CONDITIONS):
            raise ValueError(f"condition must be one of {MIXED}, {', '.join(P.CONDITIONS)}, got {condition!r}")
        self.version = version if isinstance(version, PickPlaceVersion) else version_of(version)
        self.layout = layout
        v = self.version
        super().__init__(
            P.scene_xml(layout, v.object_mass, v.grip),
            height=P.IMAGE_HEIGHT,
            width=P.IMAGE_WIDTH,
            camera=P.CAMERA,
            finger_open=P.FINGER_OPEN,
            max_steps=v.max_steps if max_steps is None else max_steps,
            render_mode=render_mode,
            robot=v.robot,
            latency_steps=latency_steps,
            frames=frames,
        )
        self.condition = condition
        m = self.model
        self._object_joint = m.body(P.OBJECT_BODY).jntadr[0]
        self._object_geom = {m.geom(P.OBJECT_GEOM).id}
        cues = [cup_body(i) for i in range(len(layout.places))] if layout.cue == CUPS else [TILE_BODY]
        self._cup_geoms = {m.geom(name).id for name in cues} if layout.cue == CUPS else set()
        self._cups = [m.body(name).mocapid[0] for name in cues]
        self._tile_geom = m.geom(cues[0]).id
        self.scene: dict = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """A new episode. options override the draws: `start` (x, y) m, `orientation` (an ORIENTATIONS key),
        `taken` (a bool per place), `change_step` (v0: int, or None for no change), `change_share` (v1: float, or None
        for no change)."""
        super().reset(seed=seed)
        options = options or {}
        m, d, rng = self.model, self.data, self.np_random
        mujoco.mj_resetData(m, d)
        jitter = rng.uniform(-self.version.start_jitter, self.version.start_jitter, 2)
        home = self.version.start
        start = np.asarray(options.get("start", (home[0] + jitter[0], home[1] + jitter[1])), np.float64)
        scene = self._draw_scene(options)
        self.scene = scene
        self.place_gripper((*start, home[2]), P.FINGER_OPEN)
        root = m.jnt_qposadr[self._object_joint]
        d.qpos[root : root + 3] = (*scene["object_xy"], self.layout.object_half[2])
        d.qpos[root + 3 : root + 7] = np.roll(yaw_quaternion(scene["object_yaw"]), 1)
        self._set_cups(scene["taken"])
        mujoco.mj_forward(m, d)
        self._steps, self._lifted, self._dropped, self._collision = 0, False, False, False
        self._lift_xy, self._valid_after_change, self._grasp_offset = None, None, None
        return self.observe(0.0), {**self._info(), "start": start.copy()}

    def _draw_scene(self, options: dict) -> dict:
        """The episode's scene: object_xy, object_yaw (deg), orientation, taken (per place), change_step (v0) or
        change_share (v1)."""
        rng, v, layout = self.np_random, self.version, self.layout
        orientations = tuple(layout.orientations)
        orientation = options.get("orientation", orientations[int(rng.integers(len(orientations)))])
        xy = np.asarray(layout.object_xy) + rng.uniform(-v.object_jitter, v.object_jitter, 2)
        yaw = layout.orientations[orientation] + rng.uniform(-v.yaw_jitter_deg, v.yaw_jitter_deg)
        condition = self.condition if self.condition != MIXED else (P.DECIDED, P.FREE)[int(rng.integers(2))]
        taken = list(rng.random(len(layout.places)) < P.OTHER_TAKEN)
        ours = layout.grasp_places(orientation)
        chosen = (int(rng.integers(len(ours))) + 1) % len(ours)  # the one valid place where the scene decides it
        for j, place in enumerate(ours):
            taken[place] = condition != P.FREE and j != chosen
        taken = [bool(t) for t in options.get("taken", taken)]
        scene = {"condition": condition, "object_xy": xy, "object_yaw": yaw, "orientation": orientation, "taken": taken}
        if v.change == IN_CARRY:
            share = float(rng.uniform(*v.change_share)) if condition == P.CHANGED else None
            return {**scene, "change_share": options.get("change_share", share), "change_step": None}
        lo, hi = P.CHANGE_STEPS
        change = int(rng.integers(lo, hi + 1)) if condition == P.CHANGED else None
        return {**scene, "change_step": options.get("change_step", change)}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Move towards the waypoint `action` (8,) for one control period, the gripper by its command;
        (observation, reward, terminated, truncated, info), reward 1 at the step that succeeds."""
        action = self.delayed(np.asarray(action, dtype=np.float64).reshape(-1))
        if self._changes_now():
            self._change_scene()
        fingers = 0.0 if action[7] < P.CLOSE_BELOW else P.FINGER_OPEN
        if not fingers and self._grasp_offset is None:
            offset = self.data.body(S.GRIPPER_BODY).xpos[:2] - self.data.body(P.OBJECT_BODY).xpos[:2]
            self._grasp_offset = float(np.linalg.norm(offset))
        physics_s = self.drive(action, fingers, self._judge)
        self._steps += 1
        observation = self.observe(physics_s)
        info = self._info()
        terminated = self._lifted and info["at_rest"] and info["released"]
        truncated = not terminated and self._steps >= self.max_steps
        return observation, float(info["is_success"] and terminated), terminated, truncated, info

    def _changes_now(self) -> bool:
        """Whether the table changes before this step acts: v0 at the drawn step; v1 once the bar is lifted and the
        gripper has covered the drawn share of the way from where it lifted the bar to the place valid until now."""
        if self.version.change != IN_CARRY:
            return self._steps == self.scene["change_step"]
        share = self.scene["change_share"]
        if share is None or self.scene["change_step"] is not None or self._lift_xy is None:
            return False
        valid = self._valid()
        if not valid:
            return False
        place = np.asarray(self.layout.places[valid[0]][1])
        gripper = self.data.body(S.GRIPPER_BODY).xpos[:2]
        way = float(np.linalg.norm(place - self._lift_xy))
        return way > 0 and 1 - float(np.linalg.norm(place - gripper)) / way >= share

    def _change_scene(self) -> None:
        """The cue shows the grasp's next place as the valid one (the `changed` condition): with two places, the cup on
        the taken one moves to the other."""
        ours = self.layout.grasp_places(self.scene["orientation"])
        taken = list(self.scene["taken"])
        valid = [j for j, place in enumerate(ours) if not taken[place]]
        following = (valid[0] + 1) % len(ours)
        for j, place in enumerate(ours):
            taken[place] = j != following
        self.scene["taken"] = taken
        self.scene["change_step"] = self._steps
        self._set_cups(taken)
        self._valid_after_change = self._valid()

    def _set_cups(self, taken: list[bool]) -> None:
        """The cue of the places `taken` (a bool per place): a cup on each (CUPS), or the tile in the colour of the
        grasp's one valid place (TILE; hidden when it has several)."""
        layout = self.layout
        if layout.cue == CUPS:
            for i, (_, xy, _) in enumerate(layout.places):
                self.data.mocap_pos[self._cups[i]] = (*xy, P.CUP_HALF_HEIGHT if taken[i] else P.HIDDEN_Z)
            return
        valid = [i for i in layout.grasp_places(self.scene["orientation"]) if not taken[i]]
        shown = len(valid) == 1
        self.data.mocap_pos[self._cups[0]] = (*layout.tile_xy, P.TILE_HALF_HEIGHT if shown else P.HIDDEN_Z)
        if shown:
            self.model.geom_rgba[self._tile_geom] = layout.mat_rgba[valid[0]]

    def _judge(self) -> None:
        """After a physics step: lifted, dropped, a collision with a cup."""
        z = self.data.body(P.OBJECT_BODY).xpos[2]
        lifted, half_z = self._lifted, self.layout.object_half[2]
        self._lifted = self._lifted or z > half_z + P.LIFTED_Z
        if self._lifted and not lifted:
            self._lift_xy = self.data.body(S.GRIPPER_BODY).xpos[:2].copy()
        high = z > half_z + P.DROP_HEIGHT
        self._dropped = self._dropped or (high and not self.touching(self.gripper_geoms, self._object_geom))
        holder = self.gripper_geoms | self._object_geom
        self._collision = self._collision or self.touching(holder, self._cup_geoms)

    def judge(self, infos: list[dict], **recorded) -> PickEpisode:
        """The episode's result (sim.tasks.pick_place.scoring.judge)."""
        return judge(infos, self.layout, **recorded)

    def object_velocity(self) -> np.ndarray:
        """The bar's linear velocity (3,) m/s."""
        d, m = self.data, self.model
        dof = m.jnt_dofadr[self._object_joint]
        return d.qvel[dof : dof + 3].copy()

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The bar's position (3,) m and quaternion xyzw (4,)."""
        return self.data.body(P.OBJECT_BODY).xpos.copy(), np.roll(self.data.body(P.OBJECT_BODY).xquat, -1)

    def place_of_object(self) -> int | None:
        """The place whose mat holds the bar's whole footprint (its corners, FOOTPRINT_TOLERANCE out at most),
        or None."""
        xmat = self.data.body(P.OBJECT_BODY).xmat.reshape(3, 3)
        hx, hy, _ = self.layout.object_half
        corners = np.array([[sx * hx, sy * hy, 0.0] for sx in (-1, 1) for sy in (-1, 1)]) @ xmat.T
        corners = corners[:, :2] + self.data.body(P.OBJECT_BODY).xpos[:2]
        for i, (_, xy, _) in enumerate(self.layout.places):
            half = np.asarray(self.layout.place_half(i)) + FOOTPRINT_TOLERANCE
            if np.all(np.abs(corners - xy) <= half):
                return i
        return None

    def _valid(self) -> list[int]:
        """The places free now that fit the bar's orientation."""
        return [i for i in self.layout.grasp_places(self.scene["orientation"]) if not self.scene["taken"][i]]

    def _info(self) -> dict:
        place = self.place_of_object()
        valid = self._valid()
        z = float(self.data.body(P.OBJECT_BODY).xpos[2])
        released = not self.touching(self.gripper_geoms, self._object_geom)
        at_rest = bool(np.linalg.norm(self.object_velocity()) < P.REST_SPEED and z < self.layout.object_half[2] + 0.005)
        success = self._lifted and not self._dropped and not self._collision and at_rest and released
        return {
            "is_success": bool(success and place in valid),
            "lifted": self._lifted,
            "dropped": self._dropped,
            "collision": self._collision,
            "released": released,
            "at_rest": at_rest,
            "place": place,
            "valid": valid,
            "condition": self.scene["condition"],
            "orientation": self.scene["orientation"],
            "taken": list(self.scene["taken"]),
            "change_step": self.scene["change_step"],
            "valid_after_change": self._valid_after_change,
            "grasp_offset_m": self._grasp_offset,
        }
