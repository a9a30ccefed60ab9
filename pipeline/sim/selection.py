"""Stage `select` of `cnep sim`: of each trained model's candidate checkpoints (`cnep train --candidates`,
models.candidates), keep the one that succeeds most in closed loop on validation episodes, as diffusion policy keeps
the checkpoints its rollouts score best. Where no environment scores them (`cnep train`), the lowest validation error
stays the rule.

Each candidate is exported (`cnep export`, under OUT/selection while it runs) and run by the online protocol in every
condition of the task, `selection_episodes` episodes each, on the validation seeds (pipeline.sim.validation: never
reported). The winner has the highest success; ties go to the lower validation error, then the later step. Its weights
and config.json become the checkpoint's, config.json recording the choice under `selection` (every candidate's step,
validation error and success, the seeds, the winner); the candidates and their exports are removed. Episodes are
seeded and run one thread each, so the same seeds give the same choice.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from types import SimpleNamespace

from cnep.models import load_checkpoint, read_checkpoint_config, save_checkpoint
from cnep.outputs import signals_held
from cnep.pipeline.evaluate.pool import run_counted
from cnep.pipeline.export.config import ExportConfig
from cnep.pipeline.export.stage import export
from cnep.pipeline.sim.config import ONLINE, PickPlaceConfig, SimConfig
from cnep.pipeline.sim.loop import episodes_of, evaluate_policy, open_task_policy
from cnep.pipeline.sim.validation import seeds_record, validation_seeds
from cnep.pipeline.train.constants import CANDIDATES_DIR
from cnep.sim.task import Task
from cnep.sim.tasks import find_task

log = logging.getLogger(__name__)

SELECTION_DIR = "selection"  # under OUT while the stage runs: the candidates' exported policies
SELECTION_KEY = "selection"  # config.json and the summary: how the kept weights were chosen
RULE = "closed-loop success on validation episodes (online); ties: lower validation error, then later step"


@dataclass(frozen=True)
class Candidate:
    """A candidate checkpoint (a folder of the checkpoint's CANDIDATES_DIR): the step its weights were validated at
    and their validation error (normalised units)."""

    path: Path
    step: int
    val_error: float


def candidates_of(checkpoint: Path) -> list[Candidate]:
    """The candidate checkpoints `cnep train --candidates` wrote into `checkpoint`, earliest first (none: [])."""
    folder = Path(checkpoint) / CANDIDATES_DIR
    found = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        result = read_checkpoint_config(path)["result"]
        found.append(Candidate(path, int(result["best_step"]), float(result["best_val_error"])))
    return sorted(found, key=lambda c: c.step)


def choose(candidates: Sequence[Candidate], success: Sequence[float]) -> Candidate:
    """The candidate with the highest `success` (one per candidate, a share); ties: the lower validation error, then
    the later step."""
    ranked = zip(candidates, success)
    return max(ranked, key=lambda pair: (pair[1], -pair[0].val_error, pair[0].step))[0]


def keep(checkpoint: Path, winner: Candidate, record: dict) -> None:
    """`winner`'s weights and config.json become `checkpoint`'s (its training log named as before), with `record`
    under SELECTION_KEY; the candidates folder is removed. Written as the running command's outputs (cnep.outputs),
    replacing the two files the same command wrote."""
    config = read_checkpoint_config(winner.path)
    extra = {key: value for key, value in config.items() if key not in ("format_version", "model")}
    extra.update(log=read_checkpoint_config(checkpoint)["log"], **{SELECTION_KEY: record})
    save_checkpoint(load_checkpoint(winner.path), checkpoint, extra, record=True)
    shutil.rmtree(Path(checkpoint) / CANDIDATES_DIR)


def select_checkpoints(
    config: SimConfig | PickPlaceConfig,
    task: Task,
    out: Path,
    checkpoints: dict[str, Path],
    extractor: Path,
    workers: int,
    held: contextlib.ExitStack | None = None,
) -> dict[str, dict]:
    """The stage: every candidate of every checkpoint (label -> checkpoint folder) scored in closed loop, `workers` at
    a time in single-threaded processes (0: in this process) under one bar, and each checkpoint's winner kept
    (`keep`); returns label -> the record its config.json holds. Nothing to choose (SelectionSettings.candidates 1):
    {}. SIGINT and SIGTERM wait while the winners are kept, and with `held` until it closes (`cnep sim` records the
    stage as finished first: pipeline.sim.partial)."""
    if not config.selection.selects:
        return {}
    found = {label: candidates_of(path) for label, path in checkpoints.items()}
    jobs = {f"{label}/{c.path.name}": c.path for label, candidates in found.items() for c in candidates}
    scores = _score_all(config, task, out, jobs, extractor, workers)
    records = {}
    with contextlib.ExitStack() as here:  # the checkpoints all as trained or all chosen from, the choice recorded
        (here if held is None else held).enter_context(signals_held())
        for label, candidates in found.items():
            scored = [scores[f"{label}/{c.path.name}"] for c in candidates]
            winner = choose(candidates, [s["success"] for s in scored])
            records[label] = selection_record(config, task, candidates, scored, winner)
            keep(checkpoints[label], winner, records[label])
            best = max(s["success"] for s in scored)
            log.info("%s: kept the weights of step %d (validation success %.2f)", label, winner.step, best)
    shutil.rmtree(out / SELECTION_DIR)
    return records


def run_seeds(config: SimConfig | PickPlaceConfig) -> dict:
    """What a `cnep sim` summary says of its seeds (pipeline.sim.validation.seeds_record): the reported episodes', and
    the validation episodes' that chose its kept checkpoints (None without a choice)."""
    chose = validation_seeds(config.selection.selection_episodes) if config.selection.selects else None
    return seeds_record(config.episode_seed, config.episodes, chose)


def selection_record(
    config: SimConfig | PickPlaceConfig, task: Task, candidates: list[Candidate], scored: list[dict], winner: Candidate
) -> dict:
    """What the kept checkpoint's config.json and the summary say of the choice."""
    seeds = validation_seeds(config.selection.selection_episodes)
    return {
        "rule": RULE,
        "protocol": ONLINE,
        "conditions": list(task.conditions),
        "episodes_per_condition": len(seeds),
        "seeds": {"first": seeds[0], "last": seeds[-1]},
        "candidates": [
            {"step": c.step, "val_error": c.val_error, **score} for c, score in zip(candidates, scored, strict=True)
        ],
        "kept_step": winner.step,
    }


def validation_settings(config: SimConfig | PickPlaceConfig, task: Task) -> SimpleNamespace:
    """The loop's settings of the validation episodes (pipeline.sim.loop.evaluate_policy): the online protocol, the
    validation seeds, the run's episode length and variant, nothing recorded."""
    seeds = validation_seeds(config.selection.selection_episodes)
    variants = {name: getattr(config, name) for name in task.variants}
    return SimpleNamespace(
        **variants,
        episodes=len(seeds),
        episode_seed=seeds[0],
        max_steps=config.max_steps,
        protocols=(ONLINE,),
        record=0,
    )


def _score_all(
    config: SimConfig | PickPlaceConfig, task: Task, out: Path, jobs: dict[str, Path], extractor: Path, workers: int
) -> dict[str, dict]:
    """Every candidate of `jobs` (name -> candidate checkpoint) scored by `_score` in `workers` processes (0: in this
    one, one after another), one bar counting their episodes; name -> score."""
    (out / SELECTION_DIR).mkdir()
    total = episodes_of(task, validation_settings(config, task)) * len(jobs)
    calls = {name: partial(_score, config, task.name, out, name, path, extractor) for name, path in jobs.items()}
    return run_counted(calls, total, "select", workers, config.quiet, unit="episode")


def _score(
    config: SimConfig | PickPlaceConfig, task_name: str, out: Path, name: str, path: Path, extractor: Path, bar
) -> dict:
    """One candidate (in a worker): exported with the run's `extractor`, run in the validation episodes; its success
    over them all and per condition (where the task has conditions)."""
    task = find_task(task_name, config.env_version)
    policy_dir = out / SELECTION_DIR / name.replace("/", "-")
    export(ExportConfig(path, policy_dir, extractor=extractor, quiet=True))
    settings = validation_settings(config, task)
    results = evaluate_policy(open_task_policy(policy_dir, task), task, settings, label=name, progress=bar.update)
    bar.update(episodes_of(task, settings), final=True)
    rates = results[ONLINE]
    if not task.conditions:
        return {"success": rates["success"]}
    by_condition = {condition: rates[condition]["success"] for condition in task.conditions}
    return {"success": sum(by_condition.values()) / len(by_condition), "by_condition": by_condition}
