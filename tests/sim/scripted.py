"""A policy without training for the simulator's tests: a `cnep.runtime.Policy` whose numpy network has two experts,
each the demonstrator's nominal path on one side (in the data's units), and a gate fixed by the test."""

from __future__ import annotations

import numpy as np

from cnep.runtime import Columns, ConditioningPolicy, Policy, PolicySpec, TimeBase
from cnep.sim import DemoDraw, demonstration_path
from cnep.sim import scene as S
from cnep.sim.tasks.obstacle import scene as O

STEPS = 40  # the paths' control steps: the time base's duration is STEPS periods


class ScriptedNetwork:
    """Encodes nothing useful; decodes the gate it was given and each side's path at the queried phases."""

    def __init__(self, gate: tuple[float, float]) -> None:
        self.gate = np.asarray(gate, dtype=np.float32)
        paths = [demonstration_path(DemoDraw(side, STEPS, 0.21, 0.8, 0.5), np.array([0.0, O.START_Y])) for side in
                 ("left", "right")]  # fmt: skip
        self.paths = np.stack(paths)  # (2, STEPS, 3): waypoint k at phase (k + 1) / STEPS

    def encode(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 4), dtype=np.float32)

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k = np.clip(np.round(query[:, 0] * STEPS).astype(int) - 1, 0, STEPS - 1)
        xyz = self.paths[:, k]  # (2, M, 3)
        rest = np.broadcast_to(np.array([0, 0, 0, 1, S.FINGER_OPEN], np.float32), (*xyz.shape[:2], 5))
        mean = np.concatenate([xyz, rest], axis=2).astype(np.float32)
        return self.gate, mean, np.full_like(mean, 0.01)


def scripted_policy(
    gate: tuple[float, float] = (0.9, 0.1), waypoints: int = O.MAX_STEPS, first_expert: str = "argmax"
) -> Policy:
    """The scripted policy (motion only: it sees no camera) with a fixed `gate` over (left, right)."""
    columns = Columns(((0, 8),), (), ((0, 8),), np.zeros(8, np.float32), np.ones(8, np.float32))
    spec = PolicySpec(columns, 2, None, (((0, 8), (0, 8)),), TimeBase(STEPS * S.CONTROL_PERIOD_S, S.CONTROL_PERIOD_S))
    conditioning = ConditioningPolicy(first_expert=first_expert)
    return Policy(ScriptedNetwork(gate), spec, waypoints=waypoints, conditioning=conditioning)
