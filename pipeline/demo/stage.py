"""`cnep demo`: the whole pipeline on the built-in tabletop demonstrations, from nothing to a Rerun recording.

Stages (each logs its progress; tqdm bars unless quiet), all under OUT:

1. generate   `recorded/{train,heldout,scene_change,free_choice}/demo_NNN.mcap`: seeded robot recordings
              (pipeline.demo.generator), scene-decided and free-choice demonstrations (both slots free);
2. ingest     `demos/...`: those Foxglove-schema MCAP files read strictly into demonstration files;
3. extract    `trajectories/...`: MobileNet-v2 features with the weights `config.weights` chooses
              (pipeline.demo.weights: ImageNet's where they can be had, else seeded random weights calibrated on
              the training demonstrations), saved to `extractor.pt` for the other splits;
4. train      `checkpoints/cnep` (`config.model`) and `checkpoints/cnmp` (one expert, parameter-matched), layout
              `scene` (queries carry the time only), seeded;
5. replay     `demo.rrd` (+ `demo.experts.json`), the one file to open: the scene-change recording through the
              CNEP; `replays/`: the held-out recordings and one held-out free-choice recording
              (`pipeline.demo.free_choice.replay_pick`);
6. summary    `summary.json` (pipeline.demo.measures, printed by pipeline.demo.report): which expert took which
              behaviour, held-out errors, the scene change's switches, where free-choice motions end, how their
              gates commit; `summary.png` (pipeline.demo.figure, when matplotlib is installed).

The behaviour labels live in each file's episode metadata and are read only for the summary.
"""

from __future__ import annotations

import json
import logging
import time
from concurrent.futures import FIRST_COMPLETED, wait
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from cnep.models import TrainConfig
from cnep.models.threads import torch_threads
from cnep.outputs import foreign_files, output_lock, recorded_by, remove_owned, write_output, writer, writing_as
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_file_as_folder
from cnep.pipeline.demo.config import DemoConfig, DemoSize
from cnep.pipeline.demo.figure import FIGURE_FILE, Scene, draw_summary
from cnep.pipeline.demo.free_choice import gate_census, generated_ends, place_outcomes, replay_pick
from cnep.pipeline.demo.generator import SPLITS, SWITCH_KEY, DemoSet, DemoSetConfig, generate
from cnep.pipeline.demo.measures import (
    POLICY,
    expert_purity,
    free_choice_commitment,
    heldout_errors,
    key,
    online_gates,
    scene_change_switches,
    trained_rows,
)
from cnep.pipeline.demo.scene import BEHAVIOURS
from cnep.pipeline.demo.weights import WeightsChoice, choose_weights
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.extract.stage import ExtractConfig, extract, views_for
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.pipeline.inputs import DEMONSTRATIONS, mcap_files
from cnep.pipeline.progress import REPORT_INTERVAL_S, BarQueue, RemoteBar, StageClock, follow_reports, progress_bar
from cnep.pipeline.replay.decisions import read_decisions
from cnep.pipeline.replay.stage import replay
from cnep.pipeline.train.constants import SCENE
from cnep.pipeline.train.stage import BAR_LEGEND, TrainStageConfig, train
from cnep.pipeline.workers import report_manager, single_thread_processes
from cnep.recordings import read_demonstration, read_trajectory

log = logging.getLogger(__name__)

LAYOUT = SCENE  # queries carry no features: the behaviour reaches the experts through the context and the gate
CNMP_ASSIGNMENT = "paper"  # one expert: the paper's term is the plain CNMP likelihood, with no balancing schedule
SUMMARY_FILE = "summary.json"
SCENE_CHANGE_MARK = "the scene changes: the block moves to the other slot"  # the view's line at the switch step
RRD_FILE = "demo.rrd"  # the scene change: what `make view` opens
REPLAYS_RRD = "replays/replay.rrd"  # the other replayed recordings, one file each beside it
PER_FILE_LOGGERS = ("cnep.pipeline.ingest", "cnep.pipeline.extract")
EXTRACTOR_FILE = "extractor.pt"
CHECKPOINT_NAMES = ("cnep", "cnmp")  # checkpoints/<name>: the CNEP and the matched CNMP


@dataclass
class DemoResult:
    """What the demo made and measured (also written to OUT/summary.json)."""

    out: Path
    rrd: list[Path]  # one .rrd per replayed recording: RRD_FILE (the scene change) first
    checkpoints: dict[str, Path]
    behaviours: dict[str, dict]  # scene-decided behaviour -> {"n", "expert", "purity", "experts": {expert: count}}
    heldout: dict[str, dict]  # model -> measures.heldout_errors: scenes read as the wrong behaviour, position errors
    feature_weights: str  # the weights the features came from: the extractor's weights name (perception.weights)
    imagenet_unavailable: str | None  # why they are not ImageNet's, when `auto` fell back (pipeline.demo.weights)
    scene_change: list[dict]  # per scene-change recording: label, switch step, expert before/after, switches
    free_choice: dict[str, dict]  # model -> place_outcomes on the held-out free-choice scenes
    free_choice_replay: list[dict]  # per replayed free-choice recording: label, choice, its step, commitment, census
    seconds: dict[str, float] = field(default_factory=dict)  # stage -> wall time (s)
    figure: Path | None = None  # FIGURE_FILE, None without matplotlib


@writing_as("demo")
def run_demo(config: DemoConfig) -> DemoResult:
    """Run every stage into `config.out` (see the module docstring); returns what was made and measured."""
    out, size = Path(config.out), config.size
    refuse_file_as_folder(out)
    seconds: dict[str, float] = {}
    owns = recorded_by(writer())
    with output_folder(out), output_lock(out, folder=True) as lock:  # the lock also clears a killed run's leftovers
        check_writable_folder(out)
        fresh = not any(p != lock for p in out.iterdir())
        if not fresh and not config.force:
            foreign = foreign_files(out, owns, keep=[lock])  # --force would refuse those: it is suggested only without
            raise PipelineError(
                f"{out}: the demo writes into a new folder and this one is not empty; give another --out, remove it"
                + (
                    f" (--force would not: {foreign[0]} is not a file a demo recorded writing)"
                    if foreign
                    else ", or add --force to replace the demo's files in it"
                )
            )
        if config.force and not fresh:
            remove_outputs(out, lock)
        try:
            with quiet_per_file_logs():
                result = _run_stages(config, out, size, seconds)
            write_output(out / SUMMARY_FILE, json.dumps(_jsonable(asdict(result)), indent=1).encode())
        except BaseException:
            if fresh:  # the folder was new or empty: a failed or interrupted demo leaves none of its files in it
                remove_owned(out, owns, keep=[lock])
            raise
    return result


def remove_outputs(out: Path, lock: Path) -> None:
    """Delete what an earlier demo wrote into `out`: refused, before anything goes, if the folder holds anything, at any
    depth, that a demo did not record writing (another command's outputs included), each file checked again as it
    goes (cnep.outputs.remove_owned); the run's `lock` stays."""
    owns = recorded_by(writer())
    foreign = foreign_files(out, owns, keep=[lock])
    if foreign:
        raise PipelineError(
            f"{foreign[0]}: --force deletes only what an earlier demo recorded writing in {out}, and this is not one "
            f"(a file of yours, or another command's output); cnep never deletes your own files: move it away, or "
            f"give another --out"
        )
    remove_owned(out, owns, keep=[lock])


@contextmanager
def quiet_per_file_logs():
    """The stages log one line per file; in the demo their progress bars say enough (kept with -v)."""
    loggers = [logging.getLogger(name) for name in PER_FILE_LOGGERS]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        if lg.getEffectiveLevel() == logging.INFO:
            lg.setLevel(logging.WARNING)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _run_stages(config: DemoConfig, out: Path, size: DemoSize, seconds: dict[str, float]) -> DemoResult:
    """The six stages in order, each timed into `seconds` (stage -> s)."""
    timed = StageClock(seconds, 6, log)
    chosen = choose_weights(config.weights, config.offline)  # before anything is made: `imagenet` may be refused
    with timed("generate", 1):
        made = _generate(config, out, size)
    with timed("ingest", 2):
        ingest(IngestConfig(src=out / "recorded", out=out / "demos", quiet=config.quiet))
    with timed("extract", 3):
        _extract(config, out, chosen.weights)
    with timed("train", 4):
        checkpoints = _train(config, out, size, started=seconds["train"])
    with timed("replay", 5):
        replayed = _replay(config, out, made, checkpoints["CNEP"])
    with timed("summary", 6):
        result = _summarise(config, out, made, chosen, checkpoints, replayed, seconds)
    return result


def _generate(config: DemoConfig, out: Path, size: DemoSize) -> DemoSet:
    """Stage 1: the seeded robot recordings under OUT/recorded (pipeline.demo.generator)."""
    return generate(
        DemoSetConfig(
            out / "recorded",
            size.per_behaviour,
            size.heldout_per_behaviour,
            1,
            size.steps,
            seed=config.seed,
            quiet=config.quiet,
            free_choice_per_side=size.free_choice_per_side,
            heldout_free_choice_per_side=size.heldout_free_choice_per_side,
        )
    )


def _extract(config: DemoConfig, out: Path, chosen_weights: str) -> None:
    """Stage 3: the training split's features with the chosen weights (random ones calibrated on its frames), saved to
    EXTRACTOR_FILE, which then extracts the other splits; every split with the size's views, else those the training
    split's size gives (`views_for`)."""
    weights = out / EXTRACTOR_FILE
    common = {
        "seed": config.seed,
        "quiet": config.quiet,
        "precision": config.precision,
        "calibrate_on": (out / "demos" / "train",),
        "offline": config.offline,
        "views": views_for(len(mcap_files(out / "demos" / "train", DEMONSTRATIONS)))
        if config.size.views is None
        else config.size.views,
    }  # int8: every split quantised on the training frames
    extract(
        ExtractConfig(
            inputs=(out / "demos" / "train",),
            out=out / "trajectories" / "train",
            weights=chosen_weights,  # random weights are calibrated on the training frames, ImageNet's used as given
            save_weights=weights,
            **common,
        )
    )
    for split in SPLITS[1:]:
        extract(
            ExtractConfig(
                inputs=(out / "demos" / split,), out=out / "trajectories" / split, weights=str(weights), **common
            )
        )


def _train(config: DemoConfig, out: Path, size: DemoSize, started: float) -> dict[str, Path]:
    """Stage 4: the CNEP and the parameter-matched CNMP, side by side in a process each or one after the other here
    (`size.side_by_side`); their checkpoints by name. started: the stage's start (time.perf_counter), for the log."""
    training = TrainConfig(
        steps=size.train_steps,
        warmup_steps=size.warmup_steps,
        val_every=size.val_every,
        seed=config.seed,
        nll_beta=config.nll_beta,
    )
    checkpoints = {"CNEP": out / "checkpoints" / CHECKPOINT_NAMES[0], "CNMP": out / "checkpoints" / CHECKPOINT_NAMES[1]}
    networks = {
        "CNEP": {"model": config.model},
        "CNMP": {"model": replace(config.model, assignment=CNMP_ASSIGNMENT), "matched_cnmp": True},
    }
    how = "side by side, one process each" if size.side_by_side else "one after the other, in this process"
    steps = "the schedule's steps" if size.train_steps is None else f"{size.train_steps} steps"
    log.info("training the CNEP and the CNMP %s (%s each)", how, steps)
    if not config.quiet:
        log.info("%s", BAR_LEGEND)
    jobs = {
        name: TrainStageConfig(
            inputs=(out / "trajectories" / "train",),
            out=path,
            layout=LAYOUT,
            training=training,
            quiet=True,
            **networks[name],
        )
        for name, path in checkpoints.items()
    }
    (train_side_by_side if size.side_by_side else train_one_after_another)(jobs, config.quiet, started)
    return checkpoints


@dataclass(frozen=True)
class _Replayed:
    """What the replay stage read and made: trajectories, each split's files; labels, each recording's behaviour
    (by split/name); switch_steps, the scene changes' steps; decided, the scene-decided training files; behaviours,
    each behaviour's expert (measures.expert_purity); traces, every held-out free choice's online gates (T, d); choice,
    the replayed free choice; rrd, the .rrd files."""

    trajectories: dict[str, list[Path]]
    labels: dict[str, str]
    switch_steps: dict[str, int]
    decided: list[Path]
    behaviours: dict[str, dict]
    traces: list[np.ndarray]
    choice: list[Path]
    rrd: list[Path]


def _replay(config: DemoConfig, out: Path, made: DemoSet, cnep: Path) -> _Replayed:
    """Stage 5: the scene change to RRD_FILE, the held-out recordings and one held-out free choice (one whose gate
    starts split, then commits) to REPLAYS_RRD, the experts named by the behaviours they take."""
    trajectories = {split: sorted((out / "trajectories" / split).glob("*.mcap")) for split in SPLITS}
    labels = {key(path): label for path, label in made.labels.items()}  # split/name is kept by every stage
    switch_steps = {key(p): int(read_demonstration(p).episode.extra[SWITCH_KEY]) for p in made.files["scene_change"]}
    decided = [p for p in trajectories["train"] if labels[key(p)] in BEHAVIOURS]  # free choices have no purity
    with torch_threads():  # small-model forwards: one thread (the extract stage may have left torch on more)
        behaviours = expert_purity(cnep, decided + trajectories["heldout"], labels)
        traces = online_gates(cnep, trajectories["free_choice"])  # every held-out free choice's gate
    replayed_choice = [trajectories["free_choice"][replay_pick(traces)]]  # one that starts split, then commits
    (out / REPLAYS_RRD).parent.mkdir(exist_ok=True)
    shown = {  # the view names each expert by the behaviours it takes, and marks where the scene changes
        "expert_labels": expert_labels(behaviours),
        "marks": {p: [(switch_steps[key(p)], SCENE_CHANGE_MARK)] for p in trajectories["scene_change"]},
    }
    rrd = [
        path
        for recordings, target in (
            (trajectories["scene_change"], out / RRD_FILE),
            (trajectories["heldout"] + replayed_choice, out / REPLAYS_RRD),
        )
        for path in replay(cnep, recordings, target, policy=POLICY, connect=None, quiet=config.quiet, **shown)
    ]  # one file each
    return _Replayed(trajectories, labels, switch_steps, decided, behaviours, traces, replayed_choice, rrd)


def _summarise(
    config: DemoConfig,
    out: Path,
    made: DemoSet,
    chosen: WeightsChoice,
    checkpoints: dict[str, Path],
    replayed: _Replayed,
    seconds: dict[str, float],
) -> DemoResult:
    """Stage 6: what the demo measures (pipeline.demo.measures) and its figure, one bar step each."""
    trajectories, labels, decided, behaviours = (
        replayed.trajectories,
        replayed.labels,
        replayed.decided,
        replayed.behaviours,
    )
    switch_steps, traces, replayed_choice, rrd = replayed.switch_steps, replayed.traces, replayed.choice, replayed.rrd
    # What the summary measures, one bar step each: held-out errors (2 models), the scene change, where the free
    # choices end (2 models), the replayed free choice, the figure.
    bar = progress_bar(total=7, desc="summary: measuring", unit="measure", quiet=config.quiet)

    def measured(value):
        bar.update(1)
        return value

    with torch_threads(), bar:  # small-model forwards: one thread (the extract stage may have left torch on more)
        result = DemoResult(
            out=out,
            rrd=rrd,
            checkpoints=checkpoints,
            behaviours=behaviours,
            heldout={
                name: measured(heldout_errors(ckpt, trajectories["heldout"], decided, labels))
                for name, ckpt in checkpoints.items()
            },
            feature_weights=read_trajectory(trajectories["train"][0]).extractor["weights"],
            imagenet_unavailable=chosen.imagenet_unavailable,
            scene_change=measured(
                scene_change_switches(out / RRD_FILE, trajectories["scene_change"], labels, switch_steps)
            ),
            free_choice={
                name: measured(place_outcomes(generated_ends(*trained_rows(ckpt, trajectories["free_choice"]))))
                for name, ckpt in checkpoints.items()
            },
            free_choice_replay=measured(
                free_choice_commitment(
                    out / REPLAYS_RRD,
                    replayed_choice,
                    made.files["free_choice"],
                    labels,
                    behaviours,
                    gate_census(traces),
                )
            ),
            seconds=seconds,
        )
        result.figure = measured(summary_figure(out, result, trajectories))
    return result


def expert_labels(behaviours: dict[str, dict]) -> dict[int, str]:
    """Each expert that some behaviour's demonstrations mostly go to -> those behaviours' names (the view shows them
    beside the expert's number); `behaviours` as `measures.expert_purity` gives them."""
    taken: dict[int, list[str]] = {}
    for behaviour, row in behaviours.items():
        taken.setdefault(int(row["expert"]), []).append(behaviour)
    return {expert: ", ".join(names) for expert, names in taken.items()}


def train_side_by_side(
    jobs: dict[str, TrainStageConfig], quiet: bool, started: float, workers: int | None = None
) -> None:
    """Train each named job in a process of its own, `workers` at a time (None: all at once; their errors reach us),
    one bar per job here, fed by the workers' reports (pipeline.progress.RemoteBar); `started`: the stage's
    perf_counter start, for the log."""
    workers = len(jobs) if workers is None else min(workers, len(jobs))
    bars = {
        name: progress_bar(total=job.training.steps, desc=f"train {name}", unit="step", quiet=quiet)
        for name, job in jobs.items()
    }
    for i, bar in enumerate(bars.values()):
        bar.set_postfix_str("starting (loading torch and the trajectories)" if i < workers else "waiting for a worker")
    try:
        with report_manager() as manager, single_thread_processes(workers, wait=False) as pool:
            reports = manager.Queue()
            pending = {pool.submit(train, job, RemoteBar(reports, name)): name for name, job in jobs.items()}
            while pending:
                finished, _ = wait(pending, timeout=REPORT_INTERVAL_S, return_when=FIRST_COMPLETED)
                follow_reports(reports, bars)
                for future in finished:
                    name = pending.pop(future)
                    future.result()
                    bars[name].close()
                    log.info("%s trained (%.1f s into the stage)", name, time.perf_counter() - started)
    finally:
        for bar in bars.values():
            bar.close()


def train_one_after_another(jobs: dict[str, TrainStageConfig], quiet: bool, started: float) -> None:
    """Train each named job in this process, in turn, with the bars `train_side_by_side` draws."""
    for name, job in jobs.items():
        with progress_bar(total=job.training.steps, desc=f"train {name}", unit="step", quiet=quiet) as bar:
            train(job, RemoteBar(BarQueue(bar), name))
        log.info("%s trained (%.1f s into the stage)", name, time.perf_counter() - started)


def summary_figure(out: Path, result: DemoResult, trajectories: dict[str, list[Path]]) -> Path | None:
    """Draw FIGURE_FILE (pipeline.demo.figure) for the scene change, the first held-out scene and the replayed free
    choice, from the replay's online gates; None, with a warning, when matplotlib (the `plots` extra) is missing."""
    try:
        import matplotlib  # noqa: F401
    except ModuleNotFoundError:
        log.warning("no summary figure: matplotlib is missing; pip install 'cnep-pipeline[plots]'")
        return None
    gates = {
        key(Path(r["recording"])): np.asarray(r["gates"])
        for rrd in (out / RRD_FILE, out / REPLAYS_RRD)
        for r in read_decisions(rrd)["recordings"]
    }
    change, choice = result.scene_change[0], result.free_choice_replay[0]
    shown = [  # title, split/name, the step to mark and what happens there
        (
            f"scene change ({change['behaviour']})",
            f"scene_change/{change['recording']}",
            change["change_step"],
            "block moves",
        ),
        ("a held-out scene", key(trajectories["heldout"][0]), None, ""),
        (
            f"free choice ({choice['scene']}, {choice['choice']} picked)",
            f"free_choice/{choice['recording']}",
            choice["carry_step"],
            "carry starts",
        ),
    ]
    scenes = [Scene(title, out / "trajectories" / name, gates[name], step, what) for title, name, step, what in shown]
    experts = {row["expert"]: behaviour for behaviour, row in result.behaviours.items()}
    return draw_summary(scenes, result.checkpoints, experts, out / FIGURE_FILE)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    return value
