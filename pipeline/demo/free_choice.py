"""The demo's free-choice measures: where generated motions place the cup, and when the replay's gate commits.

In a free-choice scene both slots of the tray are free and both places are right (pipeline.demo.scene).
A model conditioned on the first step only (the first camera frame, pose and gripper) cannot know which
slot the demonstrator picked; a generated motion is *valid* when it ends in a slot, whichever, and
*between* places when it ends anywhere else (e.g. the average of the two, ~19 cm from both slots).

- `place_outcomes(ends_xy)`: the shares of motions ending in the near slot, the far slot, or between;
- `generated_ends(trained, rows)`: where a model's motion, conditioned on each recording's first
  step, ends (xy at the last step, m);
- `gate_commitment(gates)`: for one replayed recording's (T, d) gate rows, how split the gate starts and the
  step from which one expert holds it;
- `replay_pick(traces)`: which held-out free-choice episode the demo replays, from every episode's online
  gate rows (the rule: the least certain first step among those that start split and commit), and
  `gate_census(traces)`: how many start split and how many of those commit.
"""

from __future__ import annotations

import numpy as np

from cnep.pipeline.demo.scene import SLOT_XY
from cnep.pipeline.replay.viewer import SURE_GATE
from cnep.pipeline.train.checkpoint import TrainedModel

# A motion ends in a slot when its last xy lies within this distance (m) of the slot's nominal centre. The
# slots are 12 cm squares 39 cm apart; the tray moves by 0.5 cm (std) per scene, the demonstrated place
# point by 0.6 cm (std) around the slot centre.
PLACE_TOLERANCE = 0.05
COMMIT_GATE = 0.9  # the gate has committed once one expert holds at least this probability until the end
SPLIT_GATE = SURE_GATE  # the gate starts split when no expert holds this probability at step 0


def place_outcomes(ends_xy: np.ndarray, tolerance: float = PLACE_TOLERANCE) -> dict:
    """Shares of motions whose end xy (N, 2) in m lies within `tolerance` of the near slot, the far slot, neither.

    Returns {"n", "valid" (near + far), "near", "far", "between", "distance_m" (mean distance of the ends to
    the nearest slot centre)}.
    """
    ends = np.asarray(ends_xy, dtype=float).reshape(-1, 2)
    if len(ends) == 0:
        raise ValueError("place_outcomes needs at least one motion end")
    names = list(SLOT_XY)
    distance = np.stack([np.linalg.norm(ends - np.asarray(SLOT_XY[name]), axis=1) for name in names], axis=1)  # (N, 2)
    nearest = distance.argmin(1)
    inside = distance.min(1) <= tolerance
    shares = {name: float(np.mean(inside & (nearest == i))) for i, name in enumerate(names)}
    return {
        "n": len(ends),
        "valid": float(inside.mean()),
        **shares,
        "between": float(1.0 - inside.mean()),
        "distance_m": float(distance.min(1).mean()),
    }


def generated_ends(trained: TrainedModel, rows: list[np.ndarray]) -> np.ndarray:
    """(N, 2) xy (m) at the last step of the model's motion conditioned on each recording's first step (t = 0).

    trained: a loaded checkpoint (its CNEP generates winner-take-all, the paper's inference; a CNMP is a
    one-expert CNEP); rows: each recording's (T, model width) rows.
    """
    model = trained.model
    xyz = trained.mapping.predicted_xyz(model)
    if xyz is None:
        raise ValueError("the model does not predict the end-effector position")
    ends = []
    for r in rows:
        query = r[:1, model.query_columns.numpy()] if model.config.columns.query_dim else None  # known at t = 0
        mean = model.generate(np.zeros(1), r[:1, model.obs_columns.numpy()], np.ones(1), query).mean  # (1, dy)
        ends.append(mean[0, xyz[:2]])
    return np.stack(ends)


def gate_commitment(gates: np.ndarray, threshold: float = COMMIT_GATE) -> dict:
    """How the gate (T, d) of one replayed recording starts and commits.

    Returns {"start": the two largest probabilities at step 0 with their experts [(expert, p), (expert, p)],
    "expert": the active expert at the last step, "step": the first step from which that expert holds the
    gate with at least `threshold` until the end (None if it never does)}.
    """
    gates = np.asarray(gates, dtype=float)
    top = np.argsort(gates[0])[::-1][:2]
    final = int(gates[-1].argmax())
    holds = gates[:, final] >= threshold  # (T,)
    step = None
    if holds[-1]:
        misses = np.flatnonzero(~holds)
        step = int(misses[-1] + 1) if len(misses) else 0
    return {"start": [(int(e), float(gates[0, e])) for e in top], "expert": final, "step": step}


def starts_split(gates: np.ndarray, split: float = SPLIT_GATE) -> bool:
    """True when no expert holds `split` or more of the gate (T, d) at step 0."""
    return bool(np.max(np.asarray(gates)[0]) < split)


def replay_pick(traces: list[np.ndarray], split: float = SPLIT_GATE, threshold: float = COMMIT_GATE) -> int:
    """Index of the free-choice episode to replay, from each episode's online gate rows (T_i, d).

    Among the episodes whose gate starts split (`starts_split`) and commits (`gate_commitment`: one expert holds
    `threshold` until the end), the one whose step-0 gate is least certain (lowest largest probability);
    when none does both, the least certain step 0 of all. Ties go to the lower index. Uses the gates only
    (no label, no pick), so the same model gives the same episode.
    """
    if not traces:
        raise ValueError("replay_pick needs at least one gate trace")
    first = [float(np.max(np.asarray(g)[0])) for g in traces]
    story = [
        i for i, g in enumerate(traces) if starts_split(g, split) and gate_commitment(g, threshold)["step"] is not None
    ]
    return min(story or range(len(traces)), key=lambda i: (first[i], i))


def gate_census(traces: list[np.ndarray], split: float = SPLIT_GATE, threshold: float = COMMIT_GATE) -> dict:
    """{"n": episodes, "split": whose gate starts split, "split_commit": of those, whose gate then commits}."""
    split_starts = [g for g in traces if starts_split(g, split)]
    return {
        "n": len(traces),
        "split": len(split_starts),
        "split_commit": sum(gate_commitment(g, threshold)["step"] is not None for g in split_starts),
    }
