"""`cnep sim obstacle`: from nothing to the closed-loop table, through the stages a user runs.

Stages (each logs its progress), all under OUT:

1. generate   `recorded/demo_NNN/` frames (PNG) + `poses.csv`: the scripted demonstrator driving the simulator
              (pipeline.sim.generate), as a user's robot would record them;
2. ingest     `demos/`: `cnep ingest` of those folders;
3. extract    `trajectories/`: MobileNet-v2 features with the weights `config.weights` chooses (pipeline.demo.weights:
              ImageNet's where they can be had, else seeded random ones calibrated on these frames), saved to
              `extractor.pt`;
4. train      `checkpoints/{cnep,cnmp}-seedN`: per training seed the CNEP and the parameter-matched CNMP, side by
              side (layout `scene`: observe features + pose + gripper, query with time, predict pose + gripper);
5. export     `policies/{cnep,cnmp}-seedN`: each checkpoint as a torch-free policy folder (`cnep export`);
6. closed loop `episodes/*.rrd` (the first `record` episodes of each policy and protocol) and `summary.json`: every
              exported policy in closed loop (cnep.runtime.load_policy) by each protocol (pipeline.sim.loop);
              `episode.png` (pipeline.sim.figure, with matplotlib): the first CNEP's first episode of the last
              protocol.

A failed or interrupted run leaves the folder as empty as it found it.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import as_completed
from contextlib import contextmanager
from dataclasses import asdict, fields, replace
from pathlib import Path

from cnep.models import CNEPConfig, TrainConfig
from cnep.outputs import output_lock, write_atomically
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_file_as_folder
from cnep.pipeline.demo.stage import CNMP_ASSIGNMENT, LAYOUT, quiet_per_file_logs
from cnep.pipeline.demo.weights import choose_weights
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.export.config import ExportConfig
from cnep.pipeline.export.stage import export
from cnep.pipeline.extract.stage import ExtractConfig, extract
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.pipeline.progress import StageClock
from cnep.pipeline.sim.config import LoopSettings, PickPlaceConfig, SimConfig
from cnep.pipeline.sim.figure import FIGURE_FILE
from cnep.pipeline.sim.generate import Generated, generate_demonstrations
from cnep.pipeline.sim.loop import evaluate_policy
from cnep.pipeline.sim.summary import format_table
from cnep.pipeline.train.stage import TrainStageConfig, train
from cnep.pipeline.workers import single_thread_processes
from cnep.recordings import read_trajectory
from cnep.sim import require_extra

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
EXTRACTOR_FILE = "extractor.pt"
STAGES = ("generate", "ingest", "extract", "train", "export", "closed loop")


def run_sim(config: SimConfig) -> dict:
    """Run every stage into `config.out` (module docstring); returns the summary (also OUT/summary.json)."""
    require_extra()
    return run_in_new_folder(Path(config.out), "cnep sim obstacle", lambda out: _run_stages(config, out))


def run_in_new_folder(out: Path, command: str, stages: Callable[[Path], dict]) -> dict:
    """`stages(out)` run in the new or empty folder `out` (locked for `command`), its summary written to
    OUT/summary.json; a failure or an interruption leaves the folder as empty as it found it."""
    with new_output_folder(out, command) as lock:
        try:
            with quiet_per_file_logs():
                summary = stages(out)
            write_atomically(out / SUMMARY_FILE, json.dumps(summary, indent=1).encode())
        except BaseException:
            for child in out.iterdir():
                if child != lock:
                    shutil.rmtree(child) if child.is_dir() and not child.is_symlink() else child.unlink()
            raise
    return summary


@contextmanager
def new_output_folder(out: Path, command: str) -> Iterator[Path]:
    """`out` made (or found empty) and locked for `command`, which writes into a new folder only; yields the lock's
    path (the one entry of the folder that is not an output)."""
    refuse_file_as_folder(out)
    with output_folder(out), output_lock(out, folder=True) as lock:
        check_writable_folder(out)
        if any(p != lock for p in out.iterdir()):
            raise PipelineError(f"{out}: `{command} --out` writes into a new folder and this one is not empty")
        yield lock


def _run_stages(config: SimConfig, out: Path) -> dict:
    """The six stages in order, each timed; returns the summary."""
    made, results, shared = run_stages(
        config,
        out,
        lambda recorded: generate_demonstrations(
            recorded, config.demonstrations, config.seed, config.cue, config.quiet
        ),
        lambda policies: _closed_loop(config, out, policies),
    )
    return {
        "task": config.task,
        "cue": config.cue,
        **shared,
        "demonstrations": {
            "n": len(made.folders),
            "left": made.sides.count("left"),
            "right": made.sides.count("right"),
            "clean": made.successes,
        },
        "models": by_model(results),
        "table": format_table(results),
        "seconds": shared.pop("seconds"),
    }


def run_stages(
    config: SimConfig | PickPlaceConfig,
    out: Path,
    generate: Callable[[Path], Generated],
    closed_loop: Callable[[dict[str, Path]], dict[str, dict]],
) -> tuple[Generated, dict[str, dict], dict]:
    """A task's six stages (STAGES) in order, each timed: `generate` writes the demonstrations into the folder it is
    given, `closed_loop` runs the exported policies (label -> folder). Returns the demonstrations, the closed loop's
    results and the summary's entries every task has (settings, features, imagenet_unavailable, seconds)."""
    seconds: dict[str, float] = {}
    timed = StageClock(seconds, len(STAGES), log)
    chosen = choose_weights(config.weights, config.offline)  # before anything is made: `imagenet` may be refused
    with timed("generate", 1):
        made = generate(out / "recorded")
    with timed("ingest", 2):
        ingest(IngestConfig(src=out / "recorded", out=out / "demos", quiet=config.quiet))
    with timed("extract", 3):
        extract_features(config, out, chosen.weights)
    with timed("train", 4):
        checkpoints = train_models(config, out)
    with timed("export", 5):
        policies = export_policies(checkpoints, out)
    with timed("closed loop", 6):
        results = closed_loop(policies)
    shared = {
        "settings": {k: v for k, v in asdict(config).items() if k not in ("out", "quiet")},
        "features": read_trajectory(next((out / "trajectories").glob("*.mcap"))).extractor["weights"],
        "imagenet_unavailable": chosen.imagenet_unavailable,
        "seconds": seconds,
    }
    return made, results, shared


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


def export_policies(checkpoints: dict[str, Path], out: Path) -> dict[str, Path]:
    """Stage 5: each checkpoint as a policy folder under OUT/policies; label -> folder."""
    policies = {}
    for label, checkpoint in checkpoints.items():
        policies[label] = out / "policies" / checkpoint.name
        export(ExportConfig(checkpoint, policies[label], extractor=out / EXTRACTOR_FILE, quiet=True))
        log.info("exported %s", policies[label])
    return policies


def _closed_loop(config: SimConfig, out: Path, policies: dict[str, Path]) -> dict[str, dict]:
    """Stage 6: every policy in closed loop, its first episodes recorded under OUT/episodes, the first policy's
    episode drawn into OUT/episode.png; label -> results."""
    (out / "episodes").mkdir()
    settings = LoopSettings(**{f.name: getattr(config, f.name) for f in fields(LoopSettings)})
    first = next(iter(policies))
    return {
        label: evaluate_policy(
            path, settings, label=label, recordings=out / "episodes", quiet=config.quiet,
            figure=out / FIGURE_FILE if label == first else None,
        )
        for label, path in policies.items()
    }  # fmt: skip


def train_models(config: SimConfig | PickPlaceConfig, out: Path) -> dict[str, Path]:
    """Train the CNEP and the matched CNMP for every training seed, two processes at a time; label -> checkpoint."""
    model = CNEPConfig(n_experts=config.experts, assignment=config.assignment)
    networks = {
        "CNEP": {"model": model},
        "CNMP": {"model": replace(model, assignment=CNMP_ASSIGNMENT), "matched_cnmp": True},
    }
    jobs = {
        f"{model}-seed{seed}": (out / "checkpoints" / f"{model.lower()}-seed{seed}", seed, network)
        for seed in config.train_seeds
        for model, network in networks.items()
    }
    log.info("training %d models, two at a time (%d steps each)", len(jobs), config.train_steps)
    start = time.perf_counter()
    with single_thread_processes(2) as pool:
        futures = {
            pool.submit(
                train,
                TrainStageConfig(
                    inputs=(out / "trajectories",),
                    out=path,
                    layout=LAYOUT,
                    training=replace(TrainConfig(), steps=config.train_steps, warmup_steps=config.train_steps // 6,
                                     val_every=max(1, config.train_steps // 12), patience=None, seed=seed,
                                     nll_beta=config.nll_beta),
                    quiet=True,
                    **network,
                ),
            ): label
            for label, (path, seed, network) in jobs.items()
        }  # fmt: skip
        for future in as_completed(futures):
            future.result()
            log.info("%s trained (%.0f s into the stage)", futures[future], time.perf_counter() - start)
    return {label: path for label, (path, _, _) in jobs.items()}


def by_model(results: dict[str, dict]) -> dict[str, dict[str, dict]]:
    """label `MODEL-seedN` -> {MODEL: {N: its results}}: protocol -> rates (pick and place: protocol -> condition ->
    rates)."""
    models: dict[str, dict[str, dict]] = {}
    for label, protocols in results.items():
        model, seed = label.split("-seed")
        models.setdefault(model, {})[seed] = protocols
    return models
