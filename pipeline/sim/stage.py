"""`cnep sim TASK` (obstacle, pick-place): from nothing to the closed-loop table, through the stages a user runs, for
any task of the simulator (sim.task.Task).

Stages (each logs its progress), all under OUT:

1. generate   `recorded/demo_NNN/` frames (PNG) + `poses.csv`: the task's scripted demonstrator driving the simulator
              on the environments' version `config.env_version` (pipeline.sim.generate), as a user's robot would
              record them;
2. ingest     `demos/`: `cnep ingest` of those folders, their task the task's name and version
              (pipeline.sim.config.demonstrations_task, which the checkpoints and exports record);
3. extract    `trajectories/`: MobileNet-v2 features with the weights `config.weights` chooses (pipeline.demo.weights:
              ImageNet's where they can be had, else seeded random ones calibrated on these frames), saved to
              `extractor.pt`;
4. train      `checkpoints/{cnep,cnmp}-seedN`: per training seed the CNEP and the parameter-matched CNMP, two at a
              time (layout `scene`: observe features + pose + gripper, query with time, predict pose + gripper),
              with `cnep train`'s defaults and schedule but the task's settings (pipeline.sim.recipe), each with
              `selection.candidates` candidate checkpoints (`cnep train --candidates`);
5. select     each checkpoint's weights: the candidate that succeeds most in validation episodes
              (pipeline.sim.selection, on seeds never reported: pipeline.sim.validation), recorded in its config.json
              and the summary;
6. export     `policies/{cnep,cnmp}-seedN`: each checkpoint as a torch-free policy folder (`cnep export`);
7. closed loop `episodes/*.rrd` (the first `record` episodes of each policy, protocol and condition) and
              `summary.json`: every exported policy (and with `baselines` ProMP, GMM-GMR and the nearest
              demonstration, pipeline.sim.baselines) in closed loop (cnep.runtime.load_policy) by each protocol, in
              each of the task's conditions (pipeline.sim.loop), two policies at a time in single-threaded processes;
              `episode.png` (pipeline.sim.figure, with matplotlib): the first CNEP's first episode of the last
              protocol and condition.

The stages write into a work folder beside OUT, renamed to OUT when all are complete (pipeline.folders): a failed or
interrupted run leaves OUT as it found it, and running it again starts over.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

from cnep.models import CNEPConfig, TrainConfig
from cnep.outputs import write_output, writer, writing_as
from cnep.pipeline.contract import refuse_file_as_folder
from cnep.pipeline.demo.stage import CNMP_ASSIGNMENT, LAYOUT, quiet_per_file_logs, train_side_by_side
from cnep.pipeline.demo.weights import choose_weights
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.export.config import ExportConfig
from cnep.pipeline.export.stage import export
from cnep.pipeline.extract.stage import ExtractConfig, extract
from cnep.pipeline.folders import assembled_folder
from cnep.pipeline.progress import RemoteBar, StageClock
from cnep.pipeline.sim.baselines import CHECKPOINTS, baseline_jobs, baseline_policy, environment_pose_noise
from cnep.pipeline.sim.config import PickPlaceConfig, SimConfig, demonstrations_task, trained_conditioning
from cnep.pipeline.sim.extras import require_extras
from cnep.pipeline.sim.figure import FIGURE_FILE
from cnep.pipeline.sim.generate import generate_demonstrations, ingest_demonstrations
from cnep.pipeline.sim.loop import episodes_of, evaluate_policy, for_task, open_task_policy
from cnep.pipeline.sim.pool import run_counted
from cnep.pipeline.sim.selection import run_seeds, select_checkpoints
from cnep.pipeline.sim.summary import format_table
from cnep.pipeline.train.stage import TrainStageConfig
from cnep.recordings import read_trajectory
from cnep.sim.task import Task
from cnep.sim.tasks import find_task

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
EXTRACTOR_FILE = "extractor.pt"
STAGES = ("generate", "ingest", "extract", "train", "select", "export", "closed loop")
WORKERS = 2  # processes training the models, then running the policies in closed loop


def run_sim(config: SimConfig | PickPlaceConfig) -> dict:
    """Run every stage of the task `config.TASK` into `config.out` (module docstring); returns the summary (also
    OUT/summary.json)."""
    require_extras(config, f"cnep sim {config.TASK}")
    task = find_task(config.TASK, config.env_version)
    config = for_task(config, task)
    with writing_as(f"sim {task.name}"):
        return run_in_new_folder(Path(config.out), lambda work: _run_stages(config, task, work))


def run_in_new_folder(out: Path, stages: Callable[[Path], dict]) -> dict:
    """`stages(work)` run in a work folder unique to the run beside `out`, its summary written there as SUMMARY_FILE,
    and the work folder renamed to `out` (a new or empty folder) when all is complete (pipeline.folders); a failure or
    an interruption leaves `out` as it was, with anything the user put there, and nothing of the run's (a kill -9
    leaves the work folder, which the next run into `out` removes)."""
    with assembled_folder(out, lambda: refuse_unless_new(out)) as work:
        with quiet_per_file_logs():
            summary = stages(work)
        write_output(work / SUMMARY_FILE, json.dumps(summary, indent=1).encode())
    return summary


def refuse_unless_new(out: Path) -> None:
    """PipelineError unless `out` is missing or an empty folder: the command writes into a new folder only."""
    refuse_file_as_folder(out)
    if out.is_dir() and any(out.iterdir()):
        raise PipelineError(f"{out}: `cnep {writer()} --out` writes into a new folder and this one is not empty")


def _run_stages(config: SimConfig | PickPlaceConfig, task: Task, out: Path) -> dict:
    """The stages (STAGES) in order, each timed; returns the summary."""
    seconds: dict[str, float] = {}
    timed = StageClock(seconds, len(STAGES), log)
    chosen = choose_weights(config.weights, config.offline)  # before anything is made: `imagenet` may be refused
    variants = {name: getattr(config, name) for name in task.variants}
    with timed("generate", 1):
        made = generate_demonstrations(
            task, out / "recorded", config.demonstrations, config.seed, config.quiet, **variants
        )
    with timed("ingest", 2):
        ingest_demonstrations(
            out / "recorded", out / "demos", demonstrations_task(task.name, task.version), config.quiet
        )
    with timed("extract", 3):
        extract_features(config, out, chosen.weights)
    with timed("train", 4):
        checkpoints = train_models(config, out, started=seconds["train"])
    with timed("select", 5):
        selected = select_checkpoints(config, task, out, checkpoints, out / EXTRACTOR_FILE, WORKERS)
    with timed("export", 6):
        policies = export_policies(checkpoints, out)
    with timed("closed loop", 7):
        results = _closed_loop(config, task, out, policies)
    return {
        "task": task.name,
        "env_version": task.version,
        **variants,
        "settings": {k: v for k, v in asdict(config).items() if k not in ("out", "quiet")},
        "features": read_trajectory(next((out / "trajectories").glob("*.mcap"))).extractor["weights"],
        "imagenet_unavailable": chosen.imagenet_unavailable,
        "demonstrations": {
            "n": len(made.folders),
            **task.describe_demonstrations(made.behaviours),
            "clean": made.successes,
        },
        "seeds": run_seeds(config),
        "selection": selected,
        "models": by_model(results),
        "table": format_table(results, task),
        "seconds": seconds,
    }


def extract_features(config: SimConfig | PickPlaceConfig, out: Path, weights: str) -> None:
    """Stage 3: the demonstrations' features under OUT/trajectories, the weights saved to OUT/extractor.pt."""
    extract(
        ExtractConfig(
            inputs=(out / "demos",),
            out=out / "trajectories",
            weights=weights,
            save_weights=out / EXTRACTOR_FILE,
            seed=config.seed,
            quiet=config.quiet,
            offline=config.offline,
        )
    )


def train_models(config: SimConfig | PickPlaceConfig, out: Path, started: float) -> dict[str, Path]:
    """Stage 4: the CNEP and the matched CNMP for every training seed (`training_jobs`), WORKERS at a time, a bar
    each; label -> checkpoint. started: the stage's start (time.perf_counter), for the log."""
    jobs = training_jobs(config, out)
    steps = "the schedule's steps" if config.train_steps is None else f"{config.train_steps} steps"
    log.info("training %d models, %d at a time (%s each)", len(jobs), WORKERS, steps)
    train_side_by_side(jobs, config.quiet, started, workers=WORKERS)
    return {label: Path(job.out) for label, job in jobs.items()}


def training_jobs(config: SimConfig | PickPlaceConfig, out: Path) -> dict[str, TrainStageConfig]:
    """The training of the CNEP and the matched CNMP for every training seed, on OUT/trajectories: label
    (`MODEL-seedN`) -> its job, the checkpoint OUT/checkpoints/`model-seedN`."""
    model = CNEPConfig(n_experts=config.experts, assignment=config.assignment)
    networks = {
        "CNEP": {"model": model},
        "CNMP": {"model": replace(model, assignment=CNMP_ASSIGNMENT), "matched_cnmp": True},
    }
    jobs = {}
    for seed in config.train_seeds:
        training = TrainConfig(steps=config.train_steps, seed=seed, nll_beta=config.nll_beta)  # the schedule's rest
        for name, network in networks.items():
            jobs[f"{name}-seed{seed}"] = TrainStageConfig(
                inputs=(out / "trajectories",), out=out / CHECKPOINTS / f"{name.lower()}-seed{seed}", layout=LAYOUT,
                training=training, conditioning=trained_conditioning(config),
                candidates=config.selection.candidates, quiet=True, **network,
            )  # fmt: skip
    return jobs


def export_policies(checkpoints: dict[str, Path], out: Path) -> dict[str, Path]:
    """Stage 5: each checkpoint as a policy folder under OUT/policies; label -> folder."""
    policies = {}
    for label, checkpoint in checkpoints.items():
        policies[label] = out / "policies" / checkpoint.name
        export(ExportConfig(checkpoint, policies[label], extractor=out / EXTRACTOR_FILE, quiet=True))
    return policies


def _closed_loop(
    config: SimConfig | PickPlaceConfig, task: Task, out: Path, policies: dict[str, Path]
) -> dict[str, dict]:
    """Stage 6: every policy (and the baselines, per training seed fitted with that seed's CNEP's normaliser, feature
    graph and conditioning) in closed loop, WORKERS at a time in single-threaded processes, one bar counting their
    episodes; its first episodes recorded under OUT/episodes, the first policy's drawn into OUT/episode.png; label ->
    results."""
    (out / "episodes").mkdir()
    jobs = {label: (path, None) for label, path in policies.items()}
    if config.baselines:
        jobs.update(baseline_jobs(config.train_seeds, policies))
    figure = {next(iter(policies)): out / FIGURE_FILE}
    calls = {
        label: partial(evaluate_one, config, task.name, out, label, *job, figure=figure.get(label))
        for label, job in jobs.items()
    }
    return run_counted(calls, episodes_of(task, config) * len(jobs), "closed loop", WORKERS, config.quiet)


def evaluate_one(
    config: SimConfig | PickPlaceConfig,
    task_name: str,
    out: Path,
    label: str,
    path: Path,
    baseline: tuple[str, int] | None,
    bar: RemoteBar,
    figure: Path | None,
) -> dict:
    """One policy's closed loop (in a worker): the exported policy `path`, or the baseline `baseline` (its name and
    training seed) fitted beside the exported CNEP `path`, its waypoints covering the task's episode (a plan for
    PLANNED, which `max_steps` cuts short or holds at its end; ONLINE acts on the first)."""
    task = find_task(task_name, config.env_version)
    if baseline is None:
        policy = open_task_policy(path, task)  # the conditioning it was trained with
    else:
        (name, seed), trajectories = baseline, sorted((out / "trajectories").glob("*.mcap"))
        noise = environment_pose_noise(task, config)
        policy = baseline_policy(name, path, trajectories, config.pca, task.max_steps, seed, noise)
    results = evaluate_policy(
        policy, task, config, label=label, recordings=out / "episodes", figure=figure, progress=bar.update
    )
    bar.update(episodes_of(task, config), final=True)
    return results


def by_model(results: dict[str, dict]) -> dict[str, dict[str, dict]]:
    """label `MODEL-seedN` -> {MODEL: {N: its results}}: protocol -> rates (or protocol -> condition -> rates)."""
    models: dict[str, dict[str, dict]] = {}
    for label, protocols in results.items():
        model, seed = label.split("-seed")
        models.setdefault(model, {})[seed] = protocols
    return models
