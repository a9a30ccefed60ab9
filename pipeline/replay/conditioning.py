"""Online conditioning of a recording: the gate's decision at every step, as a robot would see the steps.

    decisions = decide(model, rows, timestamps_ns, ConditioningPolicy())

An `OnlineConditioner` (models.online) takes the steps in order and re-evaluates the gate at every
step; the gate probabilities, the active expert, the switches and, when the model predicts the pose,
the active expert's predicted remaining path from each step are what the replay logs and writes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cnep.models import CNEP, ConditioningPolicy, ExpertSwitch, OnlineConditioner
from cnep.pipeline.replay.viewer import SURE_GATE

DEFAULT_PREDICTION_POINTS = 25  # points of the predicted remaining trajectory drawn per step


@dataclass
class Decisions:
    """What the gate decided at each step of one recording.

    gates (T, d), each row sums to 1; experts (T,) the active expert per step (the policy's rule); switches: one
    per change of the active expert;
    predictions (T, P, 3) the active expert's predicted remaining path (xyz) from each step, or None
    when the model does not predict the pose.
    """

    gates: np.ndarray
    experts: np.ndarray
    switches: list[ExpertSwitch]
    predictions: np.ndarray | None

    def unsure(self, sure: float = SURE_GATE) -> np.ndarray:
        """(T,) bool: the active expert holds less than `sure` of the gate at that step."""
        return self.gates[np.arange(len(self.experts)), self.experts] < sure

    def share(self) -> np.ndarray:
        """(d,) fraction of the steps each expert was active."""
        return np.bincount(self.experts, minlength=self.gates.shape[1]) / len(self.experts)


def decide(
    model: CNEP,
    rows: np.ndarray,
    timestamps_ns: np.ndarray,
    policy: ConditioningPolicy,
    xyz: list[int] | None = None,
    prediction_points: int = DEFAULT_PREDICTION_POINTS,
) -> Decisions:
    """Step an online conditioner through `rows` (T, model width) at `timestamps_ns` (T,)."""
    T, d = len(rows), model.n_experts
    online = OnlineConditioner(model, horizon=T, policy=policy)
    gates, experts = np.empty((T, d)), np.empty(T, dtype=np.int64)
    predictions = np.empty((T, prediction_points, 3), dtype=np.float32) if xyz is not None else None
    switches = []
    for k in range(T):
        step = online.step(rows[k], int(timestamps_ns[k]))
        gates[k], experts[k] = step.gate, step.expert
        if step.switch is not None:
            switches.append(step.switch)
        if predictions is not None:
            mean, _ = online.predict(np.linspace(step.t, 1.0, prediction_points))  # (P, dy)
            predictions[k] = mean[:, xyz]
    return Decisions(gates, experts, switches, predictions)
