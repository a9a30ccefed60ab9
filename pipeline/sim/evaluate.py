"""`cnep sim eval POLICY`: one given policy (an exported folder or a checkpoint) in closed loop, on the task and the
environments' version it was trained on (or `task`, `env_version`: pipeline.sim.config.with_task); the table on
screen, and with `out` a folder holding `summary.json` (the episode seeds it reports, which never meet the validation
seeds of pipeline.sim.validation; per protocol, and condition where the task has conditions, the rates and every
episode's row), the recordings of the first episodes and `episode.png` (pipeline.sim.figure), assembled beside it and
renamed into place when complete (pipeline.folders), never inside the policy it reads. The same settings and episode
seeds as the `cnep sim` run that trained the policy give the same rows as its summary: the run trains its
conditioning into its policies (pipeline.sim.config.trained_conditioning)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from cnep.outputs import write_output, writing_as
from cnep.pipeline.contract import refuse_inputs
from cnep.pipeline.folders import assembled_folder
from cnep.pipeline.progress import progress_bar
from cnep.pipeline.sim.config import EvalConfig, with_task
from cnep.pipeline.sim.extras import require_extras
from cnep.pipeline.sim.figure import FIGURE_FILE
from cnep.pipeline.sim.loop import episodes_of, evaluate_policy, for_task, open_task_policy
from cnep.pipeline.sim.partial import SUMMARY_FILE, refuse_unless_new
from cnep.pipeline.sim.summary import format_table
from cnep.pipeline.sim.validation import seeds_record
from cnep.sim.tasks import find_task


@writing_as("sim eval")
def run_eval(config: EvalConfig) -> dict:
    """Evaluate `config.policy` (module docstring); returns the summary written to OUT/summary.json."""
    require_extras(config, "cnep sim eval")
    config = with_task(config)
    config = for_task(config, find_task(config.task, config.env_version))
    label = Path(config.policy).name
    if config.out is None:
        results = {label: _evaluate(config, label, None)}
        return _summary(config, results)
    out = Path(config.out)
    refuse_inputs([out], [Path(config.policy), *([Path(config.extractor)] if config.extractor else [])])
    with assembled_folder(out, lambda: refuse_unless_new(out)) as work:  # complete or absent, as `cnep sim` writes
        results = {label: _evaluate(config, label, work)}
        summary = _summary(config, results)
        write_output(work / SUMMARY_FILE, json.dumps(summary, indent=1).encode())
    return summary


def _evaluate(config: EvalConfig, label: str, out: Path | None) -> dict:
    """The policy's results on its task (pipeline.sim.loop), its first episodes recorded into `out` (None: none)."""
    task = find_task(config.task, config.env_version)
    policy = open_task_policy(config.policy, task, config.conditioning, extractor=config.extractor)
    figure = out / FIGURE_FILE if out is not None else None
    with progress_bar(total=episodes_of(task, config), desc=label, unit="episode", quiet=config.quiet) as bar:
        return evaluate_policy(
            policy, task, config, label=label, recordings=out, figure=figure, progress=lambda n: bar.update(n - bar.n)
        )


def _summary(config: EvalConfig, results: dict) -> dict:
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in asdict(config).items() if k != "quiet"}
    table = format_table(results, find_task(config.task, config.env_version))
    seeds = seeds_record(config.episode_seed, config.episodes, None)  # it chooses nothing: reported seeds only
    return {"settings": settings, "seeds": seeds, "results": next(iter(results.values())), "table": table}
