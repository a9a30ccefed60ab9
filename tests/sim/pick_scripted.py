"""A pick-and-place policy without training for the simulator's tests: a `cnep.runtime.Policy` whose numpy network
has one expert per place, each the demonstrator's nominal path to it (the bar where it lies on average, the start
at its centre), and a gate fixed by the test."""

from __future__ import annotations

import numpy as np

from cnep.runtime import Columns, ConditioningPolicy, Policy, PolicySpec, TimeBase
from cnep.runtime.gripper import GripperCommand
from cnep.sim import PickDraw, pick_path
from cnep.sim import scene as S
from cnep.sim.tasks.pick_place import scene as P

STEPS = tuple(hi for _, hi in P.PHASE_STEPS.values())  # the slowest demonstration: each phase's most steps


class PickNetwork:
    """Encodes nothing useful; decodes the gate it was given and each place's path at the queried phases."""

    def __init__(self, gate: tuple[float, ...]) -> None:
        self.gate = np.asarray(gate, dtype=np.float32)
        paths = []
        for place, (_, _, orientation) in enumerate(P.PLACES):
            draw = PickDraw(place, STEPS, 0.0, (0.0, 0.0), P.CARRY_Z)
            paths.append(pick_path(draw, np.asarray(P.START), P.OBJECT_XY, P.ORIENTATIONS[orientation]))
        self.paths = np.stack(paths).astype(np.float32)  # (4, T, 8): waypoint k at phase (k + 1) / T

    def encode(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 4), dtype=np.float32)

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.paths.shape[1]
        k = np.clip(np.round(query[:, 0] * n).astype(int) - 1, 0, n - 1)
        mean = self.paths[:, k]  # (4, M, 8)
        return self.gate, mean, np.full_like(mean, 0.01)


def pick_policy(gate: tuple[float, ...], waypoints: int = 1, closed: float = 0.0) -> Policy:
    """The scripted pick-and-place policy (motion only: it sees no camera) with a fixed `gate` over the places,
    predicting `waypoints` steps ahead (a whole episode's plan for the planned protocol); `closed`: its gripper
    command's closed value (m, as recordings that measure the opening read it on an object)."""
    columns = Columns(((0, 8),), (), ((0, 8),), np.zeros(8, np.float32), np.ones(8, np.float32))
    time_base = TimeBase(sum(STEPS) * S.CONTROL_PERIOD_S, S.CONTROL_PERIOD_S)
    gripper = GripperCommand.from_demonstrations(np.array([closed, P.FINGER_OPEN]))
    spec = PolicySpec(columns, len(P.PLACES), None, (((0, 8), (0, 8)),), time_base, gripper=gripper)
    return Policy(PickNetwork(gate), spec, waypoints=waypoints, conditioning=ConditioningPolicy())
