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

The stages write into `.OUT.partial` beside OUT, renamed to OUT when all are complete (pipeline.sim.partial), where
STAGES_FILE records the run's settings and each finished stage with its result and files. A run stopped after a stage
leaves OUT as it found it and keeps the stages it finished there (and the closed loop's finished policies): the same
command again resumes at the next stage (the same seeds: its summary is a straight run's); one with other settings is
refused (`--force`: start over).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

from cnep.models import CNEPConfig, TrainConfig
from cnep.outputs import writing_as
from cnep.pipeline.demo.stage import CNMP_ASSIGNMENT, LAYOUT, quiet_per_file_logs, train_side_by_side
from cnep.pipeline.demo.weights import WeightsChoice, choose_weights
from cnep.pipeline.evaluate.pool import as_finished
from cnep.pipeline.export.config import ExportConfig
from cnep.pipeline.export.stage import export
from cnep.pipeline.extract.stage import ExtractConfig, extract
from cnep.pipeline.progress import RemoteBar
from cnep.pipeline.sim.baselines import CHECKPOINTS, baseline_jobs, baseline_policy, environment_pose_noise
from cnep.pipeline.sim.config import PickPlaceConfig, SimConfig, trained_conditioning
from cnep.pipeline.sim.extras import require_extras
from cnep.pipeline.sim.figure import FIGURE_FILE
from cnep.pipeline.sim.generate import generate_demonstrations, ingest_demonstrations
from cnep.pipeline.sim.loop import episodes_of, evaluate_policy, for_task, open_task_policy
from cnep.pipeline.sim.partial import PartialRun, partial_run
from cnep.pipeline.sim.selection import run_seeds, select_checkpoints
from cnep.pipeline.sim.summary import format_table
from cnep.pipeline.train.stage import TrainStageConfig
from cnep.recordings import read_trajectory
from cnep.sim.task import Task
from cnep.sim.tasks import find_task

log = logging.getLogger(__name__)

EXTRACTOR_FILE = "extractor.pt"
CLOSED_LOOP = "closed loop"
STAGES = ("generate", "ingest", "extract", "train", "select", "export", CLOSED_LOOP)
WORKERS = 2  # processes training the models, then running the policies in closed loop


def run_sim(config: SimConfig | PickPlaceConfig) -> dict:
    """Run every stage of the task `config.TASK` into `config.out` (module docstring), resuming the stages a stopped
    run of the same settings finished; returns the summary (also OUT/summary.json)."""
    require_extras(config, f"cnep sim {config.TASK}")
    task = find_task(config.TASK, config.env_version)
    config = for_task(config, task)
    out = Path(config.out)
    with writing_as(f"sim {task.name}"), partial_run(out, run_settings(config), len(STAGES), config.force) as run:
        with quiet_per_file_logs():
            summary = _run_stages(config, task, run)
        run.publish(out, summary)
    return summary


def run_settings(config: SimConfig | PickPlaceConfig) -> dict:
    """What makes a run (its summary's `settings`, and what a resumed run must share): every setting but where it
    writes and how it speaks."""
    return {k: v for k, v in asdict(config).items() if k not in ("out", "quiet", "force")}


def _run_stages(config: SimConfig | PickPlaceConfig, task: Task, run: PartialRun) -> dict:
    """The stages (STAGES) in order, each timed, those `run` finished before kept; returns the summary."""
    out = run.work
    # before anything is made (`imagenet` may be refused); the features' once they are extracted
    chosen = None if run.done("extract") else choose_weights(config.weights, config.offline)
    variants = {name: getattr(config, name) for name in task.variants}
    made = run.stage("generate", 1, lambda: generate(config, task, out, variants))
    run.stage("ingest", 2, lambda: ingest_demonstrations(out / "recorded", out / "demos", task, config.quiet))
    weights = run.stage("extract", 3, lambda: extract_chosen(config, out, chosen))
    checkpoints = {label: Path(job.out) for label, job in training_jobs(config, out).items()}
    run.stage("train", 4, lambda: train_models(config, out, started=run.seconds["train"]))
    selected = run.stage(
        "select", 5, lambda: select_checkpoints(config, task, out, checkpoints, out / EXTRACTOR_FILE, WORKERS, run.held)
    )  # its choice changes the trained checkpoints: recorded before a signal takes effect
    policies = {label: policy_folder(out, checkpoint) for label, checkpoint in checkpoints.items()}
    run.stage("export", 6, lambda: export_policies(checkpoints, out))
    results = run.stage(CLOSED_LOOP, 7, lambda: _closed_loop(config, task, run, policies))
    return {
        "task": task.name,
        "env_version": task.version,
        **variants,
        "settings": run_settings(config),
        "features": read_trajectory(next((out / "trajectories").glob("*.mcap"))).extractor["weights"],
        "imagenet_unavailable": weights["imagenet_unavailable"],
        "demonstrations": {"n": made["n"], **task.describe_demonstrations(made["behaviours"]), "clean": made["clean"]},
        "seeds": run_seeds(config),
        "selection": selected,
        "models": by_model(results),
        "table": format_table(results, task),
        "seconds": run.seconds,
    }


def extract_chosen(config: SimConfig | PickPlaceConfig, out: Path, chosen: WeightsChoice) -> dict:
    """Stage 3 (`extract_features`) with the weights `chosen`; what the summary says of the choice."""
    extract_features(config, out, chosen.weights)
    return {"imagenet_unavailable": chosen.imagenet_unavailable}


def generate(config: SimConfig | PickPlaceConfig, task: Task, out: Path, variants: dict) -> dict:
    """Stage 1: the task's demonstrations under OUT/recorded; what the summary says of them: how many, what each did
    (Task.behaviours), how many are clean."""
    made = generate_demonstrations(task, out / "recorded", config.demonstrations, config.seed, config.quiet, **variants)
    return {"n": len(made.folders), "behaviours": made.behaviours, "clean": made.successes}


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
            views=config.views,
        )
    )


def train_models(config: SimConfig | PickPlaceConfig, out: Path, started: float) -> None:
    """Stage 4: the CNEP and the matched CNMP for every training seed (`training_jobs`), WORKERS at a time, a bar
    each. started: the stage's start (time.perf_counter), for the log."""
    jobs = training_jobs(config, out)
    steps = "the schedule's steps" if config.train_steps is None else f"{config.train_steps} steps"
    log.info("training %d models, %d at a time (%s each)", len(jobs), WORKERS, steps)
    train_side_by_side(jobs, config.quiet, started, workers=WORKERS)


def training_jobs(config: SimConfig | PickPlaceConfig, out: Path) -> dict[str, TrainStageConfig]:
    """The training of the CNEP and the matched CNMP for every training seed, on OUT/trajectories: label
    (`MODEL-seedN`) -> its job, the checkpoint OUT/checkpoints/`model-seedN`."""
    model = CNEPConfig(
        n_experts=config.experts, assignment=config.assignment, feature_components=config.feature_components
    )
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


def export_policies(checkpoints: dict[str, Path], out: Path) -> None:
    """Stage 6: each checkpoint (label -> folder) as a policy folder under OUT/policies (`policy_folder`)."""
    for checkpoint in checkpoints.values():
        export(ExportConfig(checkpoint, policy_folder(out, checkpoint), extractor=out / EXTRACTOR_FILE, quiet=True))


def policy_folder(out: Path, checkpoint: Path) -> Path:
    """Where stage 6 exports `checkpoint`: OUT/policies/ under the checkpoint's name."""
    return out / "policies" / checkpoint.name


def _closed_loop(
    config: SimConfig | PickPlaceConfig, task: Task, run: PartialRun, policies: dict[str, Path]
) -> dict[str, dict]:
    """Stage 7: every policy (and the baselines, per training seed fitted with that seed's CNEP's normaliser, feature
    graph and conditioning) in closed loop, WORKERS at a time in single-threaded processes, one bar counting their
    episodes; its first episodes recorded under OUT/episodes, the first policy's drawn into OUT/episode.png; label ->
    results. Each policy is a part of the stage (pipeline.sim.partial): recorded with its files when it finishes, and
    kept where a stopped run finished it."""
    out = run.work
    (out / "episodes").mkdir(exist_ok=True)
    jobs = {label: (path, None) for label, path in policies.items()}
    if config.baselines:
        jobs.update(baseline_jobs(config.train_seeds, policies))
    kept = {label: result for label, result in run.kept_parts(CLOSED_LOOP).items() if label in jobs}
    if kept:
        log.info("closed loop: %d of %d policies finished before, kept", len(kept), len(jobs))
    figure = {next(iter(policies)): out / FIGURE_FILE}
    calls = {
        label: partial(evaluate_one, config, task.name, out, label, *job, figure=figure.get(label))
        for label, job in jobs.items()
        if label not in kept
    }
    done = dict(kept)
    for label, results in (
        []
        if not calls
        else as_finished(
            calls, episodes_of(task, config) * len(calls), CLOSED_LOOP, WORKERS, config.quiet, unit="episode"
        )
    ):
        files = sorted((out / "episodes").glob(f"{label}-*.rrd")) + [
            p for p in [figure.get(label)] if p and p.is_file()
        ]
        run.part(CLOSED_LOOP, label, results, files)
        done[label] = results
    return {label: done[label] for label in jobs}


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
