"""What each expert of a trained CNEP stands for, where the training demonstrations say it: their tasks.

    experts = demonstration_experts(model, packed, my_train)   # training-set index -> expert
    labels = expert_labels(experts, [f.task for f in data.files])   # expert -> the task of most of its demonstrations

A demonstration goes to the expert with the highest gate probability when the model is conditioned on all of its
steps. Each demonstration's task is the `task` of its episode metadata (`cnep ingest --task`, a LeRobot dataset's
episode task); where the training demonstrations name fewer than two tasks the experts keep their numbers only.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence

import numpy as np

from cnep.models import CNEP
from cnep.pipeline.train.packed import PackedColumns


def gate_of(model: CNEP, rows: np.ndarray) -> np.ndarray:
    """The gate (d,) of a model conditioned on every step of a demonstration (T, model width), raw values."""
    T = len(rows)
    t = np.arange(T) / max(T - 1, 1)  # (T,)
    obs = rows[:, model.obs_columns.cpu().numpy()]  # (T, obs_dim)
    query = rows[:1, model.query_columns.cpu().numpy()] if model.config.columns.query_dim else None
    return model.generate(t, obs, t[:1], query).gate


def demonstration_experts(model: CNEP, packed: PackedColumns, part: Sequence[int]) -> dict[int, int]:
    """Training-set index -> the expert each of files `part` (packed in `packed`) goes to."""
    starts, lengths = packed.span(part)
    return {
        index: int(gate_of(model, np.asarray(packed.rows[a : a + n])).argmax())
        for index, a, n in zip(part, starts.tolist(), lengths.tolist())
    }


def expert_labels(experts: Mapping[int, int], tasks: Sequence[str]) -> dict[int, str]:
    """Expert -> the task of most of the demonstrations that go to it (ties: the first in sorted order), for the
    experts some demonstration goes to; {} where the demonstrations `experts` names carry fewer than two tasks.

    experts: training-set index -> expert; tasks: each training-set file's task ("" for none)."""
    named = {index: tasks[index] for index in experts if tasks[index]}
    if len(set(named.values())) < 2:
        return {}
    taken: dict[int, Counter] = {}
    for index, task in named.items():
        taken.setdefault(experts[index], Counter())[task] += 1
    return {expert: min(counts, key=lambda task: (-counts[task], task)) for expert, counts in sorted(taken.items())}
