"""The closed loop's table on screen, for any task: one line per policy, protocol and (where the task has conditions)
condition, in the task's columns (Task.columns)."""

from __future__ import annotations

from cnep.sim.task import Task

POLICY_WIDTH = 18  # characters of the policy column: the label, a model and its seed (`GMM-GMR-seed0`)


def format_table(results: dict[str, dict], task: Task) -> str:
    """The on-screen table of `results` (label: a model and its seed -> protocol -> rates, or -> condition -> rates
    where the task has conditions)."""
    keys = [("policy", POLICY_WIDTH), ("protocol", 8), *([("condition", 9)] if task.conditions else [])]
    head = " ".join([*(f"{name:<{width}}" for name, width in keys), *(c.cell(c.head) for c in task.columns)])
    lines = [head, "-" * len(head)]
    for label, protocols in results.items():
        for protocol, results_of in protocols.items():
            for condition, rates in results_of.items() if task.conditions else [(None, results_of)]:
                cells = [label, protocol, *([condition] if task.conditions else [])]
                line = [f"{cell:<{width}}" for cell, (_, width) in zip(cells, keys)]
                lines.append(" ".join([*line, *(c.cell(c.value(rates)) for c in task.columns)]))
    return "\n".join(lines)
