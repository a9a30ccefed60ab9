"""What a policy needs to know besides its networks: how an observation becomes a model row, and its time base.

A robot's observation is an RGB frame and a state vector (STATE_NAMES: the end effector's xyz in m and its
quaternion xyzw, then the gripper, as the recordings store them). The model row (`Columns.width` columns)
takes the frame's features in the `features` span and state entries by `state` (pairs of spans); the
predicted columns are named after the state entries they are (`action_names`). `cnep export` writes a spec
into the manifest, and loading a checkpoint builds the same spec, so both backends read observations alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cnep.runtime.conditioning import Columns, ConditioningPolicy
from cnep.runtime.errors import PolicyError
from cnep.runtime.gripper import GripperCommand
from cnep.runtime.spans import span_indices
from cnep.runtime.timebase import TimeBase

STATE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw", "gripper")  # observation.state, in the recordings' order
GRIPPER = STATE_NAMES[-1]
POSE_NAMES = STATE_NAMES[:7]  # the end effector's position (m) and orientation


@dataclass(frozen=True)
class PolicySpec:
    """How observations become model rows.

    columns: the model row and its normaliser; n_experts: d, the gate's width; features: (start, stop) of the
    image features in the row, or None for a model that sees no camera; state: ((state_start, state_stop),
    (row_start, row_stop)) pairs; time_base: seconds -> phase (None: the checkpoint has none, give one);
    conditioning: the conditioning set and the active expert's rule; gripper: the two-state gripper's command from
    the predicted gripper (None: the prediction is the action); expert_labels: what each expert stands for, one
    entry per expert ("" where unknown; empty where the training named none: the task of most of its training
    demonstrations); tasks: the tasks of the training demonstrations (their episodes' `task`; empty where none
    named one); image_key: the observation key of the training recordings' camera where they name it (a LeRobot
    dataset's, `observation.images.top`; None: any one image); image_size: (height, width) in pixels of the training
    frames (None: unknown, any size is resized); max_step: state name -> the largest change of that pose entry
    between two steps of the training demonstrations (the data's unit: m for x y z), which bounds each step after a
    switch of expert (runtime.Policy; None: unknown, unbounded); recipe: the settings the model was trained with, as
    its checkpoint's config.json holds them (`model`: models.CNEPConfig, `training`: models.TrainConfig with its
    schedule; None: unknown).
    """

    columns: Columns
    n_experts: int
    features: tuple[int, int] | None
    state: tuple[tuple[tuple[int, int], tuple[int, int]], ...]
    time_base: TimeBase | None
    conditioning: ConditioningPolicy = ConditioningPolicy()
    gripper: GripperCommand | None = None
    expert_labels: tuple[str, ...] = ()
    tasks: tuple[str, ...] = ()
    image_key: str | None = None
    image_size: tuple[int, int] | None = None
    max_step: dict[str, float] | None = None
    recipe: dict | None = None

    def __post_init__(self) -> None:
        width = self.columns.width
        if isinstance(self.tasks, str) or not all(isinstance(task, str) for task in self.tasks):
            raise PolicyError(f"tasks must be a list of the training demonstrations' tasks, got {self.tasks!r}")
        object.__setattr__(self, "tasks", tuple(self.tasks))
        if self.image_key is not None and not (isinstance(self.image_key, str) and self.image_key):
            raise PolicyError(
                f"image_key must be an observation key (a non-empty string) or None, got {self.image_key!r}"
            )
        if self.image_size is not None:
            size = tuple(self.image_size)
            if len(size) != 2 or not all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in size):
                raise PolicyError(f"image_size must be (height, width) in pixels or None, got {self.image_size!r}")
            object.__setattr__(self, "image_size", size)
        if self.max_step is not None:
            steps = dict(self.max_step)
            if not all(
                name in POSE_NAMES and isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < math.inf
                for name, v in steps.items()
            ):
                raise PolicyError(
                    f"max_step maps pose entries ({', '.join(POSE_NAMES)}) to finite steps >= 0, got {self.max_step!r}"
                )
            object.__setattr__(self, "max_step", {name: float(v) for name, v in steps.items()})
        if int(self.n_experts) < 1:
            raise PolicyError(f"a policy needs at least one expert, got n_experts={self.n_experts}")
        object.__setattr__(self, "n_experts", int(self.n_experts))
        labels = tuple(str(label) for label in self.expert_labels)
        if labels and len(labels) != self.n_experts:
            raise PolicyError(f"expert_labels names {len(labels)} experts, the policy has {self.n_experts}")
        object.__setattr__(self, "expert_labels", labels)
        if self.features is not None:
            a, b = map(int, self.features)
            if not 0 <= a < b <= width:
                raise PolicyError(f"the features span ({a}, {b}) does not fit a model row of {width} columns")
            object.__setattr__(self, "features", (a, b))
        pairs = tuple(((int(s0), int(s1)), (int(r0), int(r1))) for (s0, s1), (r0, r1) in self.state)
        for (s0, s1), (r0, r1) in pairs:
            if not (0 <= s0 < s1 <= len(STATE_NAMES) and 0 <= r0 < r1 <= width and s1 - s0 == r1 - r0):
                raise PolicyError(
                    f"the state span ({s0}, {s1}) -> row ({r0}, {r1}) does not map {len(STATE_NAMES)} state "
                    f"entries onto a row of {width} columns"
                )
        object.__setattr__(self, "state", pairs)
        covered = sorted(span_indices([r for _, r in pairs] + ([self.features] if self.features else [])))
        if covered != list(range(width)):
            raise PolicyError(
                f"the features span {self.features} and state spans {[r for _, r in pairs]} must cover the "
                f"model row's {width} columns exactly once"
            )

    @property
    def action_names(self) -> tuple[str, ...]:
        """Names of the predicted columns, in order (a state entry's name, or `feature[i]`)."""
        names = {}
        for (s0, _), (r0, r1) in self.state:
            names.update({r0 + i: STATE_NAMES[s0 + i] for i in range(r1 - r0)})
        if self.features is not None:
            names.update({c: f"feature[{c - self.features[0]}]" for c in range(*self.features)})
        return tuple(names[c] for c in span_indices(self.columns.predicted))

    def to_dict(self) -> dict:
        """JSON-able: the manifest's `spec` entry."""
        c = self.columns
        return {
            "width": c.width,
            "n_experts": self.n_experts,
            "observed": [list(s) for s in c.observed],
            "query": [list(s) for s in c.query],
            "predicted": [list(s) for s in c.predicted],
            "normaliser": {"loc": c.loc.tolist(), "scale": c.scale.tolist()},
            "features": list(self.features) if self.features else None,
            "state_names": list(STATE_NAMES),
            "state": [[list(s), list(r)] for s, r in self.state],
            "action_names": list(self.action_names),
            "time_base": self.time_base.to_dict() if self.time_base else None,
            "conditioning": self.conditioning.to_dict(),
            "gripper": self.gripper.to_dict() if self.gripper else None,
            "expert_labels": list(self.expert_labels),
            "tasks": list(self.tasks),
            "image_key": self.image_key,
            "image_size": list(self.image_size) if self.image_size else None,
            "max_step": self.max_step,
            "recipe": self.recipe,
        }

    @classmethod
    def from_dict(cls, data: dict) -> PolicySpec:
        """The spec of `to_dict` (`gripper` may be absent: a format 1 manifest has none; `expert_labels`, `tasks`,
        `image_key`, `image_size`, `max_step` and `recipe` too, as a manifest written before they were stored has
        none); a PolicyError names the entry that is missing or wrong."""
        try:
            if tuple(data["state_names"]) != STATE_NAMES:
                raise PolicyError(
                    f"the state vector is {data['state_names']}, this runtime reads {list(STATE_NAMES)}; "
                    f"install the runtime of the cnep-pipeline that exported it"
                )
            norm = data["normaliser"]
            columns = Columns(
                tuple(map(tuple, data["observed"])),
                tuple(map(tuple, data["query"])),
                tuple(map(tuple, data["predicted"])),
                np.asarray(norm["loc"], dtype=np.float32),
                np.asarray(norm["scale"], dtype=np.float32),
            )
            if columns.width != data["width"]:
                raise PolicyError(f"the normaliser has {columns.width} columns, the row {data['width']}")
            return cls(
                columns=columns,
                n_experts=data["n_experts"],
                features=tuple(data["features"]) if data["features"] else None,
                state=tuple((tuple(s), tuple(r)) for s, r in data["state"]),
                time_base=TimeBase.from_dict(data["time_base"]) if data["time_base"] else None,
                conditioning=ConditioningPolicy.from_dict(data["conditioning"]),
                gripper=GripperCommand.from_dict(data["gripper"]) if data.get("gripper") else None,
                expert_labels=tuple(data.get("expert_labels", ())),
                tasks=data.get("tasks", ()),
                image_key=data.get("image_key"),
                image_size=tuple(data["image_size"]) if data.get("image_size") else None,
                max_step=data.get("max_step"),
                recipe=data.get("recipe"),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, PolicyError):
                raise
            raise PolicyError(f"the policy spec is incomplete or malformed ({type(exc).__name__}: {exc})") from None
