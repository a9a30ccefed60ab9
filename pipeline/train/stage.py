"""Stage `train`: trajectory MCAP files -> a CNEP checkpoint folder that replay can load.

    train(TrainStageConfig(inputs=(folder,), out=Path("ckpt"))) -> Path("ckpt")

Steps: find the trajectory files and read their summaries (one width, one feature extractor, else an
error naming the files); pick the model's columns by layout preset (pipeline.train.presets); split whole
demonstrations into training and validation; fill in the training schedule the settings leave unset (the feature
components among them) from the number of training demonstrations (models.schedule); pack the model's columns of
this process's share of them into one memory-mapped file in the work folder (pipeline.train.packed: each file read
once, its frames left unread); fit the normaliser on the training demonstrations from running moments;
train with `models.Trainer` (time normalised per demonstration to [0, 1] by its sampler), saving a
resumable state every `save_every` steps; keep the weights with the lowest validation error; stop
early after `patience` validations without improvement. Under torchrun the same call trains with
DistributedDataParallel (pipeline.train.parallel), each rank on its share of the demonstrations; only
rank 0 writes the checkpoint.

OUT gets `config.json` (model, layout, training settings with the schedule's inputs and the settings given,
extractor identity, files with sha256, the time base: the demonstrations' median duration and step period in
seconds, the gripper command, the tasks trained on, the camera's observation key and frame size, the conditioning a
policy of it runs with, the largest step of each pose entry in the demonstrations, best step and error),
`model.safetensors` and `training_log.jsonl` (one line per validation); with `candidates` N >= 2, also
`candidates/step-S/` for each of the N parts of training that kept weights (models.candidates): a complete
checkpoint each, its weights those with the lowest validation error in its part (S, the step they were validated at).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from cnep.models import CNEP, CNEPConfig, TrainConfig, Trainer, build_model, read_checkpoint_config, save_checkpoint
from cnep.models.candidates import Kept
from cnep.models.matched import matched_cnmp
from cnep.models.normaliser import Moments
from cnep.models.sampler import TrajectoryStack
from cnep.models.schedule import Schedule, schedule_of, scheduled
from cnep.models.threads import torch_threads
from cnep.models.train import split_validation
from cnep.outputs import record_written, writing_as
from cnep.pipeline import progress
from cnep.pipeline.contract import deferred_interrupts, interruption
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import find_trajectory_files
from cnep.pipeline.train.config import TrainStageConfig
from cnep.pipeline.train.constants import (
    CANDIDATES_DIR,
    CONDITIONING,
    EXPERT_LABELS,
    IMAGE_KEY,
    IMAGE_SIZE,
    LOG_FILE,
    MAX_STEP,
    STATE_FILE,
    TASKS,
)
from cnep.pipeline.train.data import TrainingSet, frame_size, load_training_set
from cnep.pipeline.train.experts import demonstration_experts, expert_labels
from cnep.pipeline.train.hold import END_HOLD_SHARE, end_holds
from cnep.pipeline.train.packed import PackedColumns, pack_columns
from cnep.pipeline.train.parallel import (
    PlacedModel,
    Processes,
    any_rank_signal,
    barrier,
    disjoint,
    from_main,
    gather,
    mean_over_ranks,
    rank_seed,
    share,
    start_processes,
    stop_processes,
)
from cnep.pipeline.train.presets import TrainingColumns, resolve_preset
from cnep.pipeline.train.state import (
    check_same_run,
    prepare_work_dir,
    publish,
    remove_work_dir,
    save_state,
    work_dir,
    write_log,
)
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_GRIPPER, BLOCK_POSE_QUAT, BLOCK_POSE_XYZ, BLOCKS_MOTION
from cnep.runtime.gripper import GripperCommand
from cnep.runtime.spec import STATE_NAMES

log = logging.getLogger(__name__)


@dataclass
class StageTrainer(Trainer):
    """`models.Trainer` that reports every step to `on_step(trainer, terms)` (the progress bar).

    The callback is handed the trainer rather than closing over it: a trainer that refers to itself
    through its callback lives on in a reference cycle, and so does the DistributedDataParallel wrapper
    with its process group. Collected only at interpreter exit, gloo's threads were torn down while
    Python finalised and the process aborted ("terminate called without an active exception", CI).
    """

    on_step: Callable[[Trainer, dict], None] | None = None
    ranks: Processes | None = None  # validating on disjoint shares: the error is the mean over these ranks
    interrupted: Callable[[], int | None] | None = None  # the signal to stop on at the end of a step, if any
    stopped_between_steps: bool = False

    def train_step(self) -> dict[str, float]:
        terms = super().train_step()
        if self.on_step is not None:
            self.on_step(self, terms)
        return terms

    def validation_error(self) -> float:
        error = super().validation_error()
        return error if self.ranks is None else mean_over_ranks(self.ranks, error)

    def after_step(self, terms: dict) -> bool:
        """The Trainer's validation and early stop, then a Ctrl-C or SIGTERM received during the step is raised:
        here, between steps, the state is the one an uninterrupted run has at this step."""
        stop = super().after_step(terms)
        signum = self.interrupted() if self.interrupted is not None else None
        if signum is not None:
            self.stopped_between_steps = True
            raise interruption(signum)
        return stop


@writing_as("train")
def train(config: TrainStageConfig, remote: progress.RemoteBar | None = None) -> Path:
    """Train a CNEP on the trajectory files of `config`; returns the checkpoint folder (config.out).

    Runs on `training.threads` torch threads per process (one by default: models.threads says why); more
    cores are used by more processes under torchrun. `remote`: where a worker process reports its steps and
    figures for its parent's bar (the demo's).
    """
    procs, device = start_processes(config.device)
    try:
        with torch_threads(config.training.threads), ExitStack() as held:
            out = _train(config, procs, device, held, remote)
    except BaseException:
        stop_processes(procs, wait=False)  # the other ranks may never reach a barrier
        raise
    stop_processes(procs, wait=True)
    return out


@dataclass(frozen=True)
class _Run:
    """What a run reads before it builds the model, alike on every rank: the files and their columns, the split of
    whole demonstrations (all of it, and this rank's share), the training settings with the schedule of that split
    filled in (models.schedule), the packed columns of that share, the gripper command
    and the largest steps they give, the run's identity and the state saved by an earlier run of it (None: a fresh
    run)."""

    data: TrainingSet
    layout: TrainingColumns
    model_config: CNEPConfig
    training: TrainConfig
    train_idx: list[int]
    val_idx: list[int]
    my_train: list[int]
    my_val: list[int]
    packed: PackedColumns
    gripper: GripperCommand | None
    holds: dict[int, int]
    max_step: dict[str, float]
    identity: dict
    saved: dict | None


def _train(
    config: TrainStageConfig,
    procs: Processes,
    device: torch.device,
    held: ExitStack,
    remote: progress.RemoteBar | None = None,
) -> Path:
    """The run; rank 0 claims OUT into `held` (its folder and lock, released when the run ends)."""
    with progress.heartbeat("reading the training files and building the model", config.quiet or not procs.is_main):
        run = _load(config, procs, held)
        config = replace(config, training=run.training)
        model, trainer, elapsed = _build(run, config, procs, device)
    _log_start(run, config, procs)
    elapsed = _loop(trainer, run, config, procs, elapsed, remote)
    labels = name_experts(model, trainer, run, procs)
    candidates = [(kept, experts_of(model, kept.state, run, procs)) for kept in kept_candidates(trainer)]
    remove_pack(run.packed, config.out, procs)
    barrier(procs)  # every rank's pack is gone before rank 0 renames the work folder into the checkpoint
    if trainer.diverged is not None and procs.is_main:
        diverged(trainer, config, run.saved is None)
    if procs.is_main:
        _publish(model, trainer, run, config, elapsed, labels, candidates)
    return config.out


def _load(config: TrainStageConfig, procs: Processes, held: ExitStack) -> _Run:
    """Read the inputs, split them, claim the work folder (resuming what it holds) and pack this rank's share."""
    data = load_training_set(find_trajectory_files(config.inputs))
    layout = resolve_preset(config.layout, data.width, data.files[0].path)
    train_idx, val_idx = split_validation(list(range(len(data.files))), config.val_fraction, config.training.seed)
    model_config = replace(config.model, columns=layout.roles)
    # each view of a training demonstration is one more scene its features are seen in (perception.views)
    scenes = sum(1 + data.files[i].views for i in train_idx)
    schedule = schedule_of(config.training, len(train_idx), procs.world_size, model_config, scenes)
    model_config = replace(model_config, feature_components=schedule.feature_components)  # what the record says
    model_config.components()  # feature_components against the layout's columns, before anything is packed
    if config.matched_cnmp:
        model_config = matched_cnmp(model_config)
    config = replace(config, training=scheduled(config.training, len(train_idx), procs.world_size, model_config))
    inputs = [f.path for f in data.files]
    given = [*map(Path, config.inputs), *inputs]  # no output inside a folder given as input either
    saved = from_main(procs, lambda: prepare_work_dir(config.out, config.resume, config.force, given, held))
    my_train, my_val = share(train_idx, procs), share(val_idx, procs)
    packed = pack_columns(data, my_train + my_val, layout, pack_base(config.out, procs))
    hashes = {i: h for part in gather(procs, packed_hashes(packed)) for i, h in part.items()}  # (sha256, rows)
    gripper = gripper_command(packed, layout, procs)
    holds = end_holds(packed, layout, gripper, procs)
    max_step = largest_steps(packed, layout, procs)
    sha256 = [hashes[i][0] for i in range(len(inputs))]
    identity = run_identity(config, data, sha256, layout, model_config, train_idx, procs, schedule, holds)
    if saved is not None:
        check_same_run(saved["identity"], identity, work_dir(config.out) / STATE_FILE)
    if procs.is_main:
        warn_identical(data, [hashes[i][1] for i in range(len(inputs))], train_idx, val_idx)
    return _Run(
        data,
        layout,
        model_config,
        config.training,
        train_idx,
        val_idx,
        my_train,
        my_val,
        packed,
        gripper,
        holds,
        max_step,
        identity,
        saved,
    )


def _build(
    run: _Run, config: TrainStageConfig, procs: Processes, device: torch.device
) -> tuple[torch.nn.Module, StageTrainer, float]:
    """The model (its normaliser fitted on the training demonstrations), its trainer, and the seconds trained so far
    (restored from the saved state when resuming)."""
    co = run.model_config.projected_columns
    moments = gather(procs, run.packed.moments(run.my_train, co))  # each rank's training share, in rank order
    fitted_on = Moments.total(moments) if disjoint(run.train_idx, procs) else moments[0]
    model = build_model(run.model_config, fitted_on, config.training.seed)
    train_held, val_held = run.packed.held(run.my_train, run.holds), run.packed.held(run.my_val, run.holds, views=False)
    train_stack = TrajectoryStack.from_rows(run.packed.rows, *run.packed.seen(run.my_train), model, train_held)
    val_stack = TrajectoryStack.from_rows(run.packed.rows, *run.packed.span(run.my_val), model, val_held)
    keep = config.candidates if config.candidates > 1 else 0
    trainer = StageTrainer(
        PlacedModel(model, device, procs),
        train_stack,
        val_stack,
        config.training,
        keep_candidates=keep,
        conditioning=config.conditioning,
    )
    if procs.distributed and disjoint(run.val_idx, procs):  # validation errors are means over the ranks' shares
        trainer.ranks = procs
        trainer.mean_error = mean_over_ranks(procs, trainer.mean_error)
    trainer.generator.manual_seed(rank_seed(config.training.seed, procs.rank))
    if run.saved is None:
        return model, trainer, 0.0
    trainer.load_state_dict(run.saved["trainer"])
    trainer.generator.set_state(run.saved["generators"][procs.rank])
    log.info("resuming at step %d of %d", trainer.step, config.training.steps)
    return model, trainer, run.saved["elapsed_s"]


def _log_start(run: _Run, config: TrainStageConfig, procs: Processes) -> None:
    """What is trained on (rank 0), and the progress bar's legend."""
    if not procs.is_main:
        return
    log.info(
        "training on %d demonstrations, validating on %d; layout %s (%d columns -> %d predicted), %d process(es)",
        len(run.train_idx),
        len(run.val_idx),
        run.layout.name,
        run.layout.roles.width,
        run.layout.roles.out_dim,
        procs.world_size,
    )
    if run.holds:
        low, high = min(run.holds.values()), max(run.holds.values())
        log.info(
            "%d demonstration(s) end less than %d%% of their steps after their gripper's last change: trained held at "
            "their last step for %s steps (pipeline.train.hold; config.json's files give each one's held_steps)",
            len(run.holds),
            round(100 * END_HOLD_SHARE),
            low if low == high else f"{low}-{high}",
        )
    if not config.quiet:
        log.info("%s", BAR_LEGEND)


def _loop(
    trainer: StageTrainer,
    run: _Run,
    config: TrainStageConfig,
    procs: Processes,
    elapsed: float,
    remote: progress.RemoteBar | None,
) -> float:
    """Train to the last step (or an early stop, or divergence), saving a resumable state every `save_every` steps;
    returns the seconds trained, across resumes. Interrupted, the state of the last step every rank finished is
    saved and the interruption re-raised with how to resume."""
    work, cfg = work_dir(config.out), config.training
    clock = time.perf_counter() - elapsed  # training time (s) counts across resumes, reading the files does not

    def state() -> dict:
        return {"identity": run.identity, "elapsed_s": time.perf_counter() - clock}

    with progress_bar(trainer, disabled=config.quiet or not procs.is_main) as bar, deferred_interrupts() as received:
        trainer.on_step = lambda stepped, terms: report_step(bar, stepped, terms, time.perf_counter() - clock, remote)
        trainer.interrupted = lambda: any_rank_signal(procs, received())
        try:
            while trainer.step < cfg.steps and not trainer.should_stop():
                trainer.run(progress=False, until=(trainer.step // config.save_every + 1) * config.save_every)
                if trainer.diverged is not None:
                    break
                save_progress(trainer, procs, work, state())
        except KeyboardInterrupt as exc:
            if trainer.stopped_between_steps:  # every rank stopped after the same step: its state resumes exactly
                save_progress(trainer, procs, work, state())
            saved_at = (
                trainer.step if trainer.stopped_between_steps else trainer.step // config.save_every * config.save_every
            )
            then = (
                f"the state of step {saved_at} is in {work}: add --resume to the same command to continue"
                if saved_at or run.saved is not None
                else "nothing was saved yet; run the command again to start over"
            )
            raise type(exc)(then) from None
    return time.perf_counter() - clock


def name_experts(model: CNEP, trainer: StageTrainer, run: _Run, procs: Processes) -> dict[int, str]:
    """Every rank: the expert each of its training demonstrations goes to under the best weights, gathered over the
    ranks; returns what each expert stands for where the demonstrations name tasks (`pipeline.train.experts`)."""
    if not trainer.best_state:  # no weights kept (a run that diverged before its first validation)
        return {}
    return experts_of(model, trainer.best_state, run, procs)


def experts_of(model: CNEP, state: dict, run: _Run, procs: Processes) -> dict[int, str]:
    """`name_experts` under the weights `state` (a state_dict of `model`, loaded into it). All ranks must call this."""
    model.load_state_dict(state)
    model.eval()
    mine = demonstration_experts(model, run.packed, run.my_train)
    experts = {index: expert for part in gather(procs, mine) for index, expert in part.items()}
    return expert_labels(experts, [f.task for f in run.data.files])


def _publish(
    model: torch.nn.Module,
    trainer: StageTrainer,
    run: _Run,
    config: TrainStageConfig,
    elapsed: float,
    labels: dict[int, str],
    candidates: list[tuple[Kept, dict[int, str]]],
) -> None:
    """Rank 0: the best weights, the run's result, what a policy needs (time base, gripper command) and what the
    experts stand for (`labels`) into the work folder's checkpoint, and the `candidates` beside them
    (`write_candidates`), recorded and renamed to OUT."""
    work = work_dir(config.out)
    model.load_state_dict(trainer.best_state)
    not_learned = trainer.not_learned()
    if not_learned is not None:
        log.warning("%s", not_learned)
    summary = {
        "best_step": trainer.best_step,
        "best_val_error": trainer.best_error,
        "mean_prediction_error": trainer.mean_error,  # what predicting the training mean scores
        "learned": not_learned is None,
        **({"warning": not_learned} if not_learned else {}),
        "steps_run": trainer.step,
        "stopped_early": trainer.step < config.training.steps,
        "elapsed_s": round(elapsed, 3),
    }
    extra = {key: value for key, value in run.identity.items() if key != "model"}  # save_checkpoint writes "model"
    time_base = run.data.time_base(run.holds).to_dict()  # the robot's seconds -> t (runtime.timebase)
    policy = {"time_base": time_base, "gripper": run.gripper.to_dict() if run.gripper else None}
    policy[EXPERT_LABELS] = {str(expert): label for expert, label in labels.items()}
    policy[TASKS] = run.data.tasks()
    policy.update(camera_layout(run))
    policy[CONDITIONING] = config.conditioning.to_dict()
    policy[MAX_STEP] = run.max_step
    save_checkpoint(model, work, {**extra, **policy, "result": summary, "log": LOG_FILE}, record=True)
    write_candidates(model, work, candidates)
    publish(work, config.out)
    log.info(
        "best validation error %.4g at step %d; %d steps in %.1f s -> %s",
        trainer.best_error,
        trainer.best_step,
        trainer.step,
        elapsed,
        config.out,
    )


def kept_candidates(trainer: Trainer) -> list[Kept]:
    """The run's candidates (models.candidates), earliest first; none when it keeps none."""
    return trainer.candidates.in_order() if trainer.candidates is not None else []


def write_candidates(model: CNEP, work: Path, candidates: list[tuple[Kept, dict[int, str]]]) -> None:
    """Each candidate (its weights and what its experts stand for) as a complete checkpoint in the checkpoint `work`'s
    CANDIDATES_DIR, `step-N` (N its step): the checkpoint's config.json with the candidate's step, validation error
    and expert labels in place of the best weights' (and no training log of its own)."""
    if not candidates:
        return
    config_json = read_checkpoint_config(work)
    for kept, labels in candidates:
        model.load_state_dict(kept.state)
        result = {**config_json["result"], "best_step": kept.step, "best_val_error": kept.error}
        extra = {k: v for k, v in config_json.items() if k not in ("format_version", "model", "log")}
        extra.update({EXPERT_LABELS: {str(e): label for e, label in labels.items()}, "result": result})
        save_checkpoint(model, work / CANDIDATES_DIR / f"step-{kept.step}", extra, record=True)


def camera_layout(run: _Run) -> dict:
    """What a policy's camera must give, for a model that sees it (runtime.PolicySpec): the observation key the
    demonstrations name (None: any one image) and the size of their frames (the first training file's first)."""
    if BLOCK_FEATURES not in run.layout.blocks:
        return {IMAGE_KEY: None, IMAGE_SIZE: None}
    size = frame_size(run.data.files[run.train_idx[0]].path)
    return {IMAGE_KEY: run.data.camera_key(), IMAGE_SIZE: list(size) if size else None}


def diverged(trainer: Trainer, config: TrainStageConfig, fresh: bool) -> None:
    """Training stopped on a validation error that is not finite or far too large (models.train.DIVERGED_ERROR):
    with weights kept from before, they become the checkpoint, with a warning; without, PipelineError (and a fresh
    run's work folder, useless now, goes)."""
    fix = (
        f"lower --lr (now {config.training.lr:g}), or look for values far outside the others in the inputs "
        f"(`cnep inspect`)"
    )
    if trainer.best_state:
        log.warning(
            "training diverged (%s); keeping the best weights, from step %d: %s",
            trainer.diverged,
            trainer.best_step,
            fix,
        )
        return
    if fresh:
        remove_work_dir(work_dir(config.out))
    raise PipelineError(f"{config.out}: training diverged before any weights could be kept ({trainer.diverged}); {fix}")


def pack_base(out: Path, procs: Processes) -> Path:
    """Where this rank packs its share's columns (`pipeline.train.packed`): the work folder (made on a machine
    whose file system rank 0's is not), named by rank and world size, so that a resume with the same ranks finds it."""
    work = work_dir(out)
    work.mkdir(parents=True, exist_ok=True)
    return work / f"columns-{procs.rank}-of-{procs.world_size}"


def packed_hashes(packed: PackedColumns) -> dict[int, tuple[str, str]]:
    """Training-set index -> (the file's sha256, its packed rows' sha256) of the files this rank packed."""
    return {i: (h, d) for i, h, d in zip(packed.indices, packed.sha256, packed.digests)}


def gripper_command(packed: PackedColumns, layout: TrainingColumns, procs: Processes) -> GripperCommand | None:
    """The two-state gripper's command chosen from every file's gripper values (runtime.gripper; the closed one: the
    value the files do not start at), gathered from the ranks' packs; None when the model has no gripper column. All
    ranks must call this."""
    span = layout.blocks.get(BLOCK_GRIPPER)
    if span is None:
        return None
    values = {i: v for part in gather(procs, packed.columns(packed.indices, span)) for i, v in part.items()}
    starts = [values[i][0] for i in sorted(values) if len(values[i])]  # each demonstration starts open
    return GripperCommand.from_demonstrations(np.concatenate([values[i] for i in sorted(values)]), starts)


def largest_steps(packed: PackedColumns, layout: TrainingColumns, procs: Processes) -> dict[str, float]:
    """State name -> the largest change of that pose entry between two consecutive steps of any demonstration (the
    data's unit: m for x y z), over every file's packed rows, gathered from the ranks' packs: how far a policy's step
    may go after a switch of expert (runtime.Policy). All ranks must call this."""
    found = {}
    for block in (BLOCK_POSE_XYZ, BLOCK_POSE_QUAT):
        span = layout.blocks.get(block)
        if span is None:
            continue
        values = packed.columns(packed.indices, span).values()  # each (T, k)
        mine = [np.abs(np.diff(v.astype(np.float64), axis=0)).max(axis=0, initial=0.0) for v in values]  # each (k,)
        ranks = gather(procs, np.max(mine, axis=0) if mine else np.zeros(span[1] - span[0]))
        first = BLOCKS_MOTION[block][0]  # where the block's entries lie in the state vector
        found.update({STATE_NAMES[first + i]: float(v) for i, v in enumerate(np.max(ranks, axis=0))})
    return found


def remove_pack(packed: PackedColumns, out: Path, procs: Processes) -> None:
    """Delete this rank's pack once training ended (its memory map stays readable until the process ends), and on a
    machine other than rank 0's, the work folder it made for it if nothing else is in it."""
    base = pack_base(out, procs)
    files = (base.with_suffix(".npy"), base.with_suffix(".json"))
    for path in files:
        path.unlink(missing_ok=True)
    record_written([], forget=files)
    if not procs.is_main:
        with contextlib.suppress(OSError):
            base.parent.rmdir()


def warn_identical(data: TrainingSet, digests: list[str], train_idx: list[int], val_idx: list[int]) -> None:
    """Warn when every validation demonstration holds the same rows as a training one (`digests`: each file's packed
    rows' sha256): the validation error then measures the training set, and early stopping and the best weights
    cannot see overfitting."""
    trained = {digests[i] for i in train_idx}
    copies = [str(data.files[i].path) for i in val_idx if digests[i] in trained]
    if copies and len(copies) == len(val_idx):
        log.warning(
            "the validation demonstration(s) %s hold the same rows as training ones: the validation error measures "
            "the training set; give distinct demonstrations",
            ", ".join(copies),
        )


def save_progress(trainer: Trainer, procs: Processes, work: Path, extra: dict) -> None:
    """Rank 0 saves the resumable state (with every rank's batch generator) and the log; all ranks must call this."""
    generators = gather(procs, trainer.generator.get_state())
    if procs.is_main:
        save_state(work / STATE_FILE, {**extra, "trainer": trainer.state_dict(), "generators": generators})
        write_log(work / LOG_FILE, trainer.history)


def run_identity(
    config: TrainStageConfig,
    data: TrainingSet,
    sha256: list[str],
    layout: TrainingColumns,
    model_config: CNEPConfig,
    train_idx: list[int],
    procs: Processes,
    schedule: Schedule,
    holds: dict[int, int],
) -> dict:
    """What makes a run: saved in config.json and compared on --resume (JSON-able, as JSON reads it back); `sha256`:
    each file's; `schedule`: the training schedule's inputs, values and the settings given instead; `holds`: the
    steps each file is held at its last step (pipeline.train.hold)."""
    trained = set(train_idx)
    files = [
        dict(f.describe(sha256[i], holds.get(i, 0)), split="train" if i in trained else "validation")
        for i, f in enumerate(data.files)
    ]
    identity = {
        "stage": "train",
        "layout": layout.to_dict(),
        "model": model_config.to_dict(),
        "training": {
            **asdict(config.training.for_assignment(model_config.assigned)),
            "val_fraction": config.val_fraction,
            "candidates": config.candidates,
            "world_size": procs.world_size,
            "batch_size_total": config.training.batch_size * procs.world_size,
            "schedule": schedule.to_dict(),
        },
        "extractor": data.extractor,
        "files": files,
    }
    return json.loads(json.dumps(identity))


def progress_bar(trainer: Trainer, disabled: bool) -> tqdm:
    return progress.progress_bar(
        total=trainer.cfg.steps, initial=trainer.step, desc="train", unit="step", quiet=disabled
    )


def report_step(bar: tqdm, trainer: Trainer, terms: dict, elapsed: float, remote: progress.RemoteBar | None) -> None:
    """Progress: the step on the bar (and on `remote`), with the figures of `bar_figures`.

    The terms dict is the one the Trainer appends to its history at validation steps, so the
    elapsed time also lands in the log there.
    """
    terms["elapsed_s"] = round(elapsed, 3)
    bar.update(1)
    if bar.disable and remote is None:
        return
    figures = bar_figures(trainer, terms)
    if remote is not None:
        remote.update(trainer.step, final=trainer.step >= trainer.cfg.steps, **figures)
    if not bar.disable:
        bar.set_postfix(figures, refresh=False)


# What the figures on a training bar mean (logged once when training starts).
BAR_LEGEND = (
    "on the bar: loss = this batch's training loss; val = the last validation error (normalised units: predicting "
    "the mean scores about 1), from the first validation on; best = the lowest validation error of the weights "
    "kept so far (kept once the experts have settled); use = the share of each batch the gate gives each expert "
    "(0.00 is an expert that is not used)"
)


def bar_figures(trainer: Trainer, terms: dict) -> dict[str, str]:
    """The figures BAR_LEGEND explains, formatted: loss, val and best once there are some, use."""
    figures = {"loss": f"{terms['loss']:.3g}"}
    if trainer.history:
        figures["val"] = f"{trainer.history[-1]['val_error']:.3g}"
    if math.isfinite(trainer.best_error):
        figures["best"] = f"{trainer.best_error:.3g}"
    figures["use"] = "/".join(f"{u:.2f}" for u in terms["usage"])
    return figures
