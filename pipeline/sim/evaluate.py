"""`cnep sim eval POLICY`: one given policy (an exported folder or a checkpoint) in closed loop; the table on screen,
and with `out` a folder holding `summary.json` (per protocol the rates and every episode's row), the recordings
of the first episodes and `episode.png` (pipeline.sim.figure)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from cnep.outputs import write_atomically
from cnep.pipeline.sim.config import EvalConfig
from cnep.pipeline.sim.figure import FIGURE_FILE
from cnep.pipeline.sim.loop import evaluate_policy
from cnep.pipeline.sim.stage import SUMMARY_FILE, new_output_folder
from cnep.pipeline.sim.summary import format_table
from cnep.sim import require_extra


def run_eval(config: EvalConfig) -> dict:
    """Evaluate `config.policy` (module docstring); returns the summary written to OUT/summary.json."""
    require_extra()
    label = Path(config.policy).name
    if config.out is None:
        results = {label: _evaluate(config, label, None)}
        return _summary(config, results)
    out = Path(config.out)
    with new_output_folder(out, "cnep sim eval"):
        results = {label: _evaluate(config, label, out)}
        summary = _summary(config, results)
        write_atomically(out / SUMMARY_FILE, json.dumps(summary, indent=1).encode())
    return summary


def _evaluate(config: EvalConfig, label: str, out: Path | None) -> dict:
    figure = out / FIGURE_FILE if out is not None else None
    return evaluate_policy(
        config.policy,
        config,
        label=label,
        extractor=config.extractor,
        recordings=out,
        figure=figure,
        quiet=config.quiet,
    )


def _summary(config: EvalConfig, results: dict) -> dict:
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in asdict(config).items() if k != "quiet"}
    return {"settings": settings, "results": next(iter(results.values())), "table": format_table(results)}
