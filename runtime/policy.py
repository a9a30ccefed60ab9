"""`Policy`: a trained CNEP in a robot's control loop, with LeRobot's interface.

    policy.reset()                                   # at the start of every episode (reset(seed=...): its draws)
    action = policy.select_action(observation)       # (dy,) the next waypoint, the gripper as its command
    result = policy.step(observation)                # waypoints, std, gate, active expert, switch, gripper command

An observation is a dict (LeRobot's keys): `observation.images.<camera>` an RGB frame (H, W, 3) uint8 of any
size (or, as LeRobot's processors hand images, (3, H, W) float in [0, 1]: converted, a copy per step),
`observation.state` the robot's state (8,) (runtime.spec.STATE_NAMES: xyz in m, quaternion xyzw,
gripper), and optionally `timestamp`, the seconds since the episode began (without it, step k is at
k * period_s of the time base). Each value may carry LeRobot's leading batch dimension of 1; then the action
has it too. Anything else is one PolicyError saying which key and what to do: a wrong type, shape or dtype, a value
that is not finite, a time that does not move forward or lies a day or more after the episode's start
(MAX_TIME_S), a position beyond MAX_POSITION_M metres on an axis, a zero quaternion or one whose length is not 1
within QUATERNION_TOLERANCE (one within it is normalised), a gripper more than GRIPPER_DEVIATIONS of the training
demonstrations' standard deviations from their mean (a "no reading" sentinel such as 3e38, another unit), a camera
other than the training recordings' or frames of another size than theirs (where the spec names them). Only the
state entries the model reads are checked. Whatever the network gives that is not finite is a PolicyError too
(runtime.conditioning): no step hands out NaN.

A switch of expert continues from where the end effector is: from the step the active expert changes until the
new expert's first waypoint lies within one step of the state, each waypoint's pose entries move at most the
training demonstrations' largest step (`PolicySpec.max_step`, per entry) from the one before it, the first from the
observed state; the new expert's path is never jumped to.

One class for both backends: the network (`runtime.conditioning.Network`) and the feature function are the
torch model and extractor (`cnep.pipeline.export.checkpoint_policy`) or the exported ONNX graphs
(`runtime.exported.load_policy`); everything else (reading the observation, the time base, the conditioning
set, the gate, the active expert, switches, the gripper command) is this code. Per step it reuses
preallocated buffers for the resized frame, the model row and the query times.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from cnep.runtime.conditioning import Conditioner, ConditioningPolicy, ExpertSwitch, Network
from cnep.runtime.constants import (
    DEFAULT_WAYPOINTS,
    GRIPPER_DEVIATIONS,
    IMAGE_KEY_PREFIX,
    MAX_POSITION_M,
    MAX_TIME_S,
    QUATERNION_TOLERANCE,
    STATE_KEY,
    TIMESTAMP_KEY,
)
from cnep.runtime.errors import PolicyError
from cnep.runtime.frames import pixel_buffer, resize_frame
from cnep.runtime.gripper import GripperCommand
from cnep.runtime.spans import span_indices
from cnep.runtime.spec import GRIPPER, POSE_NAMES, STATE_NAMES, PolicySpec
from cnep.runtime.timebase import TimeBase

Features = Callable[[np.ndarray], np.ndarray]  # uint8 pixels (1, 224, 224, 3) -> float32 features (1, F)
POSITION = [STATE_NAMES.index(name) for name in ("x", "y", "z")]  # where the state holds the position (m)
QUATERNION = [STATE_NAMES.index(name) for name in ("qx", "qy", "qz", "qw")]  # and the orientation
GRIPPER_INDEX = STATE_NAMES.index(GRIPPER)


@dataclass(frozen=True)
class PolicyStep:
    """One control step's result, in the data's units.

    waypoints, std: (W, dy) the active expert's mean and std at the next W steps (columns `action_names`; the
    gripper as predicted, a continuous value); times_s: (W,) their seconds since the episode began; gate: (d,)
    sums to 1; expert: the active expert (the policy's rule: runtime.conditioning.hand_over); switch: set when
    the active expert changed at this step (never at the first); time_s and t: this step's seconds and phase;
    gripper: the command for the next step, one of the gripper's two values (runtime.gripper), None when the
    policy has no gripper command; gripper_closed: that command as a two-state gripper executes it, True to close
    (with the gripper's own force: the closed value of a recorded opening is the width of the objects held) and
    False to open, None without a command.
    """

    step: int
    time_s: float
    t: float
    waypoints: np.ndarray
    std: np.ndarray
    times_s: np.ndarray
    gate: np.ndarray
    expert: int
    switch: ExpertSwitch | None
    gripper: float | None = None
    gripper_closed: bool | None = None


class Policy:
    """A CNEP policy for one episode at a time.

    network, features: the backend (features None for a model that sees no camera); spec: how observations
    become model rows (runtime.spec); waypoints: future steps predicted per step (W >= 1, spaced by the time
    base's period); conditioning, time_base, gripper: override the spec's; camera: the
    `observation.images.<camera>` to read (None: the only image in the observation).
    """

    def __init__(
        self,
        network: Network,
        spec: PolicySpec,
        features: Features | None = None,
        *,
        waypoints: int = DEFAULT_WAYPOINTS,
        conditioning: ConditioningPolicy | None = None,
        time_base: TimeBase | None = None,
        gripper: GripperCommand | None = None,
        camera: str | None = None,
    ) -> None:
        if waypoints < 1:
            raise PolicyError(f"waypoints must be >= 1 (the next step at least), got {waypoints}")
        if (features is None) != (spec.features is None):
            need = "needs the feature network" if features is None else "sees no camera and takes no features"
            raise PolicyError(f"this policy's model {need}")
        self.spec, self.camera = spec, camera
        self.time_base = time_base or spec.time_base
        if self.time_base is None:
            raise PolicyError(
                "this policy carries no time base (a checkpoint stores its training demonstrations' length and step "
                "period); give one: time_base=TimeBase(duration_s, period_s) in seconds, or `--time-base "
                "DURATION_S,PERIOD_S` to cnep export or cnep run"
            )
        self.gripper = gripper or spec.gripper
        # The gripper's column in the predicted ones, if the model predicts it and a command is known.
        names = spec.action_names
        self._gripper_col = names.index(GRIPPER) if self.gripper is not None and GRIPPER in names else None
        self._features = features
        used = span_indices([s for s, _ in spec.state])
        self._position = [i for i in POSITION if i in used]  # the state's xyz entries the model reads
        self._quaternion = any(i in used for i in QUATERNION)
        self._gripper_range = gripper_range(spec)  # (low, high) the gripper may read, None if the model reads none
        # The pose entries a switch bounds: their columns among the predicted, their state entries and largest steps.
        bounded = [
            (col, STATE_NAMES.index(name), (spec.max_step or {}).get(name, 0.0))
            for col, name in enumerate(names)
            if name in POSE_NAMES and STATE_NAMES.index(name) in used
        ]
        bounded = [(c, i, step) for c, i, step in bounded if step > 0]  # a pose entry that never moved: unbound
        self._bounded = tuple(np.array(x) for x in zip(*bounded)) if bounded else None  # columns, entries, steps
        self._conditioner = Conditioner(network, spec.columns, conditioning or spec.conditioning)
        self._pixels = pixel_buffer(1)  # (1, 224, 224, 3) uint8
        self._row = np.zeros(spec.columns.width, dtype=np.float32)  # (width,) the model row of this step
        self._offsets = self.time_base.period_s * np.arange(1, waypoints + 1)  # (W,) seconds ahead of this step
        self._query_t = np.empty(waypoints, dtype=np.float64)  # (W,) phases of the waypoints
        self.reset()

    @property
    def action_names(self) -> tuple[str, ...]:
        """Names of the action's (and each waypoint's) columns, e.g. ('x', 'y', 'z', ..., 'gripper')."""
        return self.spec.action_names

    @property
    def n_experts(self) -> int:
        return self.spec.n_experts

    @property
    def conditioning(self) -> ConditioningPolicy:
        """The conditioning this policy runs with: its spec's, or the one it was given."""
        return self._conditioner.policy

    @property
    def uses_camera(self) -> bool:
        """True if the model sees the camera (an observation must then carry an image)."""
        return self._features is not None

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode: empty the conditioning set; the next observation is step 0 at time 0.

        seed: the episode's draws (`ConditioningPolicy.first_expert="sample"`): the same seed gives the same first
        expert for the same observations; None continues the policy's generator (seeded 0 when it is made).
        """
        self._conditioner.reset(seed)
        self._last_time_s: float | None = None
        self._command: float | None = None  # the gripper command of the last step
        self._switching = False  # between a switch of expert and the new expert's path reached

    def select_action(self, observation: Mapping) -> np.ndarray:
        """The next waypoint (dy,) for `observation`, or (1, dy) when its state came with a batch dimension; its
        gripper column holds the gripper command (`PolicyStep.gripper`) where the policy has one."""
        result, batched = self._step(observation)
        action = result.waypoints[:1].copy() if batched else result.waypoints[0].copy()
        if result.gripper is not None:
            action[..., self._gripper_col] = result.gripper
        return action

    def step(self, observation: Mapping) -> PolicyStep:
        """Take `observation` as the episode's next step: the waypoints, their std, the gate and any switch."""
        return self._step(observation)[0]

    def _step(self, observation: Mapping) -> tuple[PolicyStep, bool]:
        if not isinstance(observation, Mapping):
            raise PolicyError(
                f"an observation is a dict with {STATE_KEY!r} (and an image {IMAGE_KEY_PREFIX}<camera>), got a "
                f"{type(observation).__name__}"
            )
        state, batched = self._read_state(observation)
        time_s = self._read_time(observation)
        if self._features is not None:
            resize_frame(self._read_image(observation), self._pixels[0])
            a, b = self.spec.features
            self._row[a:b] = self._features(self._pixels)[0]
        for (s0, s1), (r0, r1) in self.spec.state:
            self._row[r0:r1] = state[s0:s1]
        tb = self.time_base
        times = self._offsets + time_s  # (W,) the waypoints' seconds, handed out with the result
        np.divide(times, tb.duration_s, out=self._query_t)
        np.clip(self._query_t, 0.0, 1.0, out=self._query_t)
        k, t = self._conditioner.k, tb.phase(time_s)
        gate, expert, switch, mean, std = self._conditioner.step(self._row, t, self._query_t, round(time_s * 1e9))
        self._last_time_s = time_s
        mean = self._continued(mean, state, switch is not None)
        command = self._gripper_command(state, mean)
        closed = None if command is None else self.gripper.is_closed(command)
        return PolicyStep(k, time_s, t, mean, std, times, gate, expert, switch, command, closed), batched

    def _continued(self, mean: np.ndarray, state: np.ndarray, switched: bool) -> np.ndarray:
        """The waypoints (W, dy) to hand out for the active expert's `mean` at the observed `state` (8,): `mean`
        itself, but from a switch of expert until its first waypoint lies within the largest step of the state on
        every bounded entry, each waypoint's bounded entries moved at most that step from the one before it (the
        first from the state)."""
        self._switching = (self._switching or switched) and self._bounded is not None
        if not self._switching:
            return mean
        cols, entries, steps = self._bounded  # (n,) each
        position = state[entries]  # (n,) where the end effector is
        if (np.abs(mean[0, cols] - position) <= steps).all():  # the new expert's path is reached
            self._switching = False
            return mean
        continued = mean.copy()
        for i in range(len(continued)):
            position = position + np.clip(continued[i, cols] - position, -steps, steps)
            continued[i, cols] = position
        return continued

    def _gripper_command(self, state: np.ndarray, mean: np.ndarray) -> float | None:
        """The command for the first waypoint's predicted gripper (mean (W, dy)), from the last command, or at the
        episode's first step from the gripper's observed state."""
        if self._gripper_col is None:
            return None
        previous = self._command
        if previous is None:
            previous = self.gripper.nearest(float(state[GRIPPER_INDEX]))
        self._command = self.gripper.command(float(mean[0, self._gripper_col]), previous)
        return self._command

    def _read_state(self, observation: Mapping) -> tuple[np.ndarray, bool]:
        if STATE_KEY not in observation:
            raise PolicyError(
                f"the observation has no {STATE_KEY!r} (keys: {', '.join(map(str, observation)) or 'none'}); give "
                f"the robot's state ({len(STATE_NAMES)},): {', '.join(STATE_NAMES)}"
            )
        state = np.asarray(observation[STATE_KEY])
        batched = state.ndim == 2 and state.shape[0] == 1
        if state.dtype.kind not in "fiu" or state.shape not in ((len(STATE_NAMES),), (1, len(STATE_NAMES))):
            raise PolicyError(
                f"{STATE_KEY} must be a ({len(STATE_NAMES)},) array of numbers ({', '.join(STATE_NAMES)}; a leading "
                f"batch dimension of 1 is allowed), got shape {state.shape} dtype {state.dtype}"
            )
        state = state.reshape(-1).astype(np.float64)  # a copy: the quaternion may be normalised
        if not np.isfinite(state).all():
            bad = [STATE_NAMES[i] for i in np.flatnonzero(~np.isfinite(state))]
            raise PolicyError(f"{STATE_KEY} has values that are not finite ({', '.join(bad)}): {state.tolist()}")
        far = [i for i in self._position if abs(state[i]) > MAX_POSITION_M]
        if far:
            raise PolicyError(
                f"{STATE_KEY}: {STATE_NAMES[far[0]]} = {state[far[0]]:g} m is beyond the {MAX_POSITION_M:g} m a "
                f"position may lie from the robot's origin; give the end effector's position in metres"
            )
        low, high = self._gripper_range or (-np.inf, np.inf)
        if not low <= state[GRIPPER_INDEX] <= high:
            raise PolicyError(
                f"{STATE_KEY}: gripper = {state[GRIPPER_INDEX]:g} lies outside {low:.4g} to {high:.4g}, "
                f"{GRIPPER_DEVIATIONS:g} standard deviations of the training demonstrations' gripper around their "
                f"mean (a 'no reading' value, or another unit?); give the gripper's reading in the recordings' unit"
            )
        if self._quaternion:
            quat = state[QUATERNION]  # (4,) xyzw
            norm = float(np.linalg.norm(quat))
            if abs(norm - 1.0) > QUATERNION_TOLERANCE:
                raise PolicyError(
                    f"{STATE_KEY}: the quaternion (qx, qy, qz, qw) = {quat.tolist()} has length {norm:.3g}, not 1 "
                    f"(within {QUATERNION_TOLERANCE}), so it is no orientation; give a unit quaternion xyzw "
                    f"((0, 0, 0, 1) for no rotation)"
                )
            state[QUATERNION] = quat / norm
        return state, batched

    def _read_time(self, observation: Mapping) -> float:
        if TIMESTAMP_KEY not in observation:
            return self._conditioner.k * self.time_base.period_s
        value = np.asarray(observation[TIMESTAMP_KEY])
        if value.dtype.kind not in "fiu" or value.size != 1:
            raise PolicyError(
                f"{TIMESTAMP_KEY} must be one number, the seconds since the episode began, got "
                f"{str(observation[TIMESTAMP_KEY])[:80]!r} ({type(observation[TIMESTAMP_KEY]).__name__})"
            )
        time_s = float(value.reshape(()))
        if not np.isfinite(time_s) or time_s < 0:
            raise PolicyError(f"{TIMESTAMP_KEY} must be finite seconds >= 0 since the episode began, got {time_s}")
        if time_s >= MAX_TIME_S:
            raise PolicyError(
                f"{TIMESTAMP_KEY} {time_s:g} s is a day or more after the episode began (a clock's time?); give the "
                f"seconds since the episode began, under {MAX_TIME_S:g}"
            )
        if self._last_time_s is not None and time_s <= self._last_time_s:
            raise PolicyError(
                f"{TIMESTAMP_KEY} {time_s} s does not move forward (the previous step was at {self._last_time_s} s); "
                f"call reset() at the start of a new episode"
            )
        return time_s

    def _read_image(self, observation: Mapping) -> np.ndarray:
        keys = [key for key in observation if isinstance(key, str) and key.startswith(IMAGE_KEY_PREFIX)]
        trained = self.spec.image_key
        if self.camera is not None:
            key = IMAGE_KEY_PREFIX + self.camera
        elif trained is not None:
            key = trained
        else:
            key = keys[0] if len(keys) == 1 else None
        if key is None or key not in observation:
            wanted = f"{key!r}" if key else f"one {IMAGE_KEY_PREFIX}<camera> (or camera= to choose)"
            why = " (the training recordings' camera)" if key == trained and self.camera is None else ""
            raise PolicyError(
                f"this policy sees the camera: the observation needs {wanted}{why}, it has "
                f"{', '.join(keys) or 'no image'}; camera='NAME' reads {IMAGE_KEY_PREFIX}NAME instead"
            )
        frame = np.asarray(observation[key])
        if frame.ndim == 4 and frame.shape[0] == 1:
            frame = frame[0]
        if frame.dtype.kind == "f" and frame.ndim == 3 and frame.shape[0] == 3:
            frame = lerobot_image(frame, key)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3 or 0 in frame.shape:
            raise PolicyError(
                f"{key} must be an RGB frame (H, W, 3) uint8, or (3, H, W) float in [0, 1] as LeRobot hands images "
                f"(a leading batch dimension of 1 is allowed), got shape {frame.shape} dtype {frame.dtype}"
            )
        size = self.spec.image_size
        if size is not None and frame.shape[:2] != size:
            raise PolicyError(
                f"{key}: a frame of {frame.shape[1]}x{frame.shape[0]} pixels, but this policy was trained on frames of "
                f"{size[1]}x{size[0]} (width x height); give the training camera's frames at that size"
            )
        return frame


def gripper_range(spec: PolicySpec) -> tuple[float, float] | None:
    """(low, high): the gripper readings a policy of `spec` takes, GRIPPER_DEVIATIONS of the training demonstrations'
    standard deviations (its normaliser's scale) around their mean; None where the model does not read the
    gripper."""
    index = STATE_NAMES.index(GRIPPER)
    for (s0, s1), (r0, _) in spec.state:
        if s0 <= index < s1:
            loc, scale = float(spec.columns.loc[r0 + index - s0]), float(spec.columns.scale[r0 + index - s0])
            return loc - GRIPPER_DEVIATIONS * scale, loc + GRIPPER_DEVIATIONS * scale
    return None


def lerobot_image(image: np.ndarray, key: str) -> np.ndarray:
    """LeRobot's image (3, H, W) float in [0, 1] as the (H, W, 3) uint8 frame the camera gave (a copy)."""
    if not (np.isfinite(image).all() and image.min() >= 0.0 and image.max() <= 1.0):
        raise PolicyError(f"{key}: a float image must hold values in [0, 1], got {image.min()} to {image.max()}")
    return np.ascontiguousarray((image * 255.0 + 0.5).astype(np.uint8).transpose(1, 2, 0))  # (H, W, 3)
