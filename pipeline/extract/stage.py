"""Stage `extract`: demonstration MCAP files -> trajectory MCAP files of 1288-d steps [features | pose | gripper].

Each input is a demonstration file or a folder searched recursively for `*.mcap` (sorted). Outputs go
to OUT/<name> (folder inputs keep their relative paths), written atomically by the recording layer;
an input is never overwritten. An output is skipped when it is up to date: newer than its input and
made by an extractor with the same identity (perception.compatibility_key); one older than its input
is redone; any other existing output is refused unless `force` (pipeline.contract). Demonstrations without
frames become motion-only trajectories (8-d, no feature block).

With `weights="random"` the network is first calibrated on frames sampled evenly over all inputs
(perception.calibration), so every file of one run shares one extractor; save it with
`save_weights` to extract more files later with identical features.

Scale-out: `shard=(i, n)` (`cnep extract --shard I/N`) extracts the i-th of n shares of the inputs (`shard_of`:
every n-th file by output path from the i-th on), so that n jobs of any scheduler (a Slurm job array, a
Kubernetes indexed job, a loop over machines) split one data set into one --out folder; each calibrates random
weights on the frames of every input alike, so all shards share one extractor identity.
`workers` > 1 extracts the files in that many spawned processes on this machine, each
with its share of the cores (pipeline.workers.inference_threads) and the parent's extractor;
`workers="auto"` takes one per core but only as many as the job pays for (`auto_workers`: a spawned
worker costs seconds to start, measured by benchmarks/bench_extract.py). Under
`torchrun` (environment RANK, WORLD_SIZE) rank r extracts every WORLD_SIZE-th file of its shard from the r-th on
(each rank calibrates random weights on the same frames, so all ranks share one weights hash); outputs are per
file, so nothing is gathered (docs/how-to/extract-features.md, docs/how-to/cluster.md).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from cnep.models.config import check_seed
from cnep.models.schedule import FEW_DEMONSTRATIONS
from cnep.outputs import output_file, output_lock, writing_as
from cnep.perception import FeatureExtractor, PerceptionError, compatibility_key
from cnep.perception.constants import CALIBRATION_FRAMES, DEFAULT_VIEWS, FEATURE_DIM
from cnep.perception.frames import decode_image, resize_frames
from cnep.perception.views import View, Views
from cnep.perception.weights import find_imagenet_weights
from cnep.pipeline.contract import output_folder, raise_if_skipped, refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import DEMONSTRATIONS, coerce_paths, mcap_files
from cnep.pipeline.progress import heartbeat, progress_bar
from cnep.pipeline.workers import cpu_cores, inference_threads, process_pool, thread_environment
from cnep.recordings import (
    RecordingError,
    Trajectory,
    read_demonstration,
    read_summary,
    write_trajectory,
)
from cnep.recordings.constants import KIND_DEMONSTRATION, KIND_TRAJECTORY, TOPIC_IMAGE
from cnep.recordings.readers import in_file

log = logging.getLogger(__name__)

# `workers="auto"`: frames per worker process. A second worker costs seconds to start and pays only on a job this
# large at fp32, never at int8 (benchmarks/bench_extract.py, docs/results.md).
WORKER_MIN_FRAMES = 4000


@dataclass(frozen=True)
class ExtractConfig:
    """inputs: demonstration files or folders (read only); out: folder for the trajectory files (created).

    weights: `imagenet`, `random` (seeded by `seed`, calibrated on the inputs) or a state-dict path.
    backend: `auto` (fastest available for the precision: `cuda` where torch sees a GPU), `cuda`,
    `onnxruntime`, `openvino`, `torchscript` or `eager`; threads: CPU threads per process (None: the
    process's share of the cores, pipeline.workers); batch_size: frames per forward pass (None: the
    backend's default, perception.FeatureExtractor); force: re-extract up-to-date outputs and replace
    any other existing output;
    save_weights: where to save the (calibrated) weights, to reuse them as `weights` later; keep_going:
    skip inputs that fail and report them at the end; workers: processes extracting files side by side,
    or `auto` (`auto_workers`); precision: `fp32` or `int8` (quantised on frames sampled evenly over all
    inputs, like the random weights' calibration; perception.quantisation); offline: never download the
    ImageNet weights; shard: (i, n), extract only the i-th of n shares of the inputs (`shard_of`);
    calibrate_on: demonstration files or folders whose frames calibrate random weights
    and quantise int8, instead of the inputs (so that later runs over other files share the first run's
    int8 identity); views: each demonstration's features also under this many views of its frames, drawn with
    `seed` (perception.views); None: the rule's for the number of inputs (`views_for`).
    """

    inputs: tuple[Path, ...]
    out: Path
    weights: str = "imagenet"
    backend: str = "auto"
    threads: int | None = None
    batch_size: int | None = None
    seed: int = 0
    force: bool = False
    save_weights: Path | None = None
    keep_going: bool = False
    quiet: bool = False
    offline: bool = False  # never download ImageNet weights (perception.weights.find_imagenet_weights)
    workers: int | str = 1
    precision: str = "fp32"
    calibrate_on: tuple[Path, ...] = ()
    shard: tuple[int, int] = (0, 1)
    views: int | None = None

    def __post_init__(self) -> None:
        coerce_paths(self)
        if self.views is not None:
            Views(self.views, self.seed)  # checks the count
        index, count = self.shard
        if not 0 <= index < count:
            raise PipelineError(f"--shard I/N needs 0 <= I < N, got {index}/{count}")
        if self.workers != "auto" and (not isinstance(self.workers, int) or self.workers < 1):
            raise PipelineError(f"--workers must be >= 1, got {self.workers} (or `auto`: as many as the job pays for)")
        check_seed("--seed", self.seed, PipelineError)


@dataclass(frozen=True)
class Extracted:
    """What happened to one input: its output, step count, and whether it was skipped as up to date."""

    source: Path
    output: Path
    n_steps: int
    skipped: bool


@writing_as("extract")
def extract(config: ExtractConfig) -> list[Extracted]:
    """Run the stage; returns one Extracted per input demonstration of this rank's share, in input order.

    The extractor is built (and for random weights calibrated) only once a file needs it, so inputs
    without frames or outputs already up to date with fixed weights cost no network.
    """
    refuse_inputs([config.out], config.inputs, what="the output folder", whole=False)
    all_pairs = plan_outputs(config.inputs, config.out)
    if config.views is None:  # every shard and rank counts every input alike
        config = replace(config, views=views_for(len(all_pairs)))
    rank, world_size = torchrun_rank()
    pairs = shard_of(all_pairs, *config.shard)[rank::world_size]  # this job's share; all calibrate on every input
    first = rank == 0 and config.shard[0] == 0  # the one job that saves the weights
    if config.save_weights is not None:
        refuse_inputs([config.save_weights], [src for src, _ in all_pairs], "--save-weights")
        refuse_existing([config.save_weights], config.force, "weights file")
    extractor = _lazy_extractor(config, [src for src, _ in all_pairs])
    skipped: list[str] = []

    def failed(src: Path, exc: Exception) -> None:
        if not config.keep_going:
            raise exc
        log.warning("skipped %s: %s", src, exc)
        skipped.append(str(exc))

    # Under torchrun every rank writes its share into --out: rank 0 holds the lock for the run, and leaves
    # temporary files alone (another rank's, on another machine, would look like a dead process's). Shards run
    # side by side into one --out: none holds the folder's lock, each writes only its own files.
    alone = world_size == 1 and config.shard[1] == 1
    lock = output_lock(config.out, folder=True, clean=alone) if rank == 0 and config.shard[1] == 1 else None
    with output_folder(config.out), lock or contextlib.nullcontext():
        current = _current_outputs(config, pairs, extractor)
        if config.save_weights is not None and first:
            _save_weights(config.save_weights, extractor)
        done: dict[int, Extracted] = {}
        for i, (src, dst) in enumerate(pairs):
            if current[dst] is not None:
                log.info("%s is up to date, skipped", dst)
                done[i] = Extracted(src, dst, current[dst], skipped=True)
        todo = [i for i, (_, dst) in enumerate(pairs) if current[dst] is None]
        done.update(_extract_todo(config, pairs, todo, extractor, failed))
    raise_if_skipped(skipped, len(pairs), f"were extracted into {config.out}")
    return [done[i] for i in sorted(done)]


def views_for(demonstrations: int) -> int:
    """The views of each demonstration's frames extracted with `demonstrations` of them: DEFAULT_VIEWS where they
    are fewer than the training schedule's few (models.schedule.FEW_DEMONSTRATIONS), under which each view is one
    more scene the image features are seen in; else none."""
    return DEFAULT_VIEWS if demonstrations < FEW_DEMONSTRATIONS else 0


def _lazy_extractor(config: ExtractConfig, inputs: list[Path]) -> Callable[[], FeatureExtractor]:
    """A function returning the run's one extractor, built (and calibrated, on `config.calibrate_on` or else on
    `inputs`) at its first call."""
    built: list[FeatureExtractor] = []

    def extractor() -> FeatureExtractor:
        if not built:
            sources = (
                [src for given in config.calibrate_on for src in mcap_files(given, DEMONSTRATIONS)]
                if config.calibrate_on
                else inputs
            )
            built.append(build_extractor(config, sources))
        return built[0]

    return extractor


def _current_outputs(
    config: ExtractConfig, pairs: list[tuple[Path, Path]], extractor: Callable[[], FeatureExtractor]
) -> dict[Path, int | None]:
    """Each output's steps when it is up to date with its input and these weights, else None (to be written); an
    existing output that is not is refused unless `force`, a stale one (older than its input) only if cnep did not
    write it."""
    for _, dst in pairs:  # nested input folders keep their sub-folders under --out
        dst.parent.mkdir(parents=True, exist_ok=True)
    current = {dst: None if config.force else up_to_date_steps(src, dst, extractor, config.views) for src, dst in pairs}
    stale = {dst for src, dst in pairs if current[dst] is None and not _newer_than(dst, src)}
    refuse_existing(
        [dst for _, dst in pairs if current[dst] is None and dst not in stale],
        config.force,
        "output",
        " and is not this input's trajectory file from these weights and views",
    )
    refuse_existing(sorted(stale), True)  # redone without --force, but only if cnep wrote it
    return current


def _save_weights(path: Path, extractor: Callable[[], FeatureExtractor]) -> None:
    """The extractor's weights to `path`, under its lock (`--save-weights`)."""
    with output_lock(path), output_file(path) as staged:
        extractor().save_weights(staged)
    log.info("saved the extractor weights to %s (reuse them with --weights %s)", path, path)


def _extract_todo(
    config: ExtractConfig,
    pairs: list[tuple[Path, Path]],
    todo: list[int],
    extractor: Callable[[], FeatureExtractor],
    failed: Callable[[Path, Exception], None],
) -> dict[int, Extracted]:
    """Extract pairs[i] for each i in `todo`, in worker processes when the job pays for them (`workers`), else here;
    a file that fails goes to `failed`."""
    done: dict[int, Extracted] = {}
    frames = [count * (1 + config.views) for count in frame_counts([pairs[i][0] for i in todo])]
    with (
        logging_redirect_tqdm(),
        progress_bar(total=sum(frames), unit="frame", desc=f"extract {config.out.name}", quiet=config.quiet) as bar,
    ):
        workers = auto_workers([pairs[i][0] for i in todo]) if config.workers == "auto" else config.workers
        if workers > 1 and len(todo) > 1:
            jobs = [(*pairs[i], count) for i, count in zip(todo, frames)]
            done.update(extract_in_processes(jobs, todo, extractor, config, workers, bar, failed))
        else:
            for i in todo:
                try:
                    done[i] = extract_file(*pairs[i], extractor, bar, Views(config.views, config.seed))
                except (RecordingError, PerceptionError) as exc:
                    failed(pairs[i][0], exc)
    return done


def _newer_than(dst: Path, src: Path) -> bool:
    """True if `dst` exists and is not older than `src` (so it is not a stale output of `src`)."""
    return os.path.lexists(dst) and (not dst.is_file() or dst.stat().st_mtime >= src.stat().st_mtime)


def shard_of(pairs: Sequence[tuple[Path, Path]], index: int, count: int) -> list[tuple[Path, Path]]:
    """Shard `index` of `count` of the planned (input, output) pairs, in plan order: every count-th by output path
    from the index-th on. A pure function of the inputs (whatever order they are given in), so every job derives its
    own share alone; the shards are disjoint and cover the inputs."""
    by_output = sorted(range(len(pairs)), key=lambda k: str(pairs[k][1]))
    mine = set(by_output[index::count])
    return [pair for k, pair in enumerate(pairs) if k in mine]


def torchrun_rank() -> tuple[int, int]:
    """(rank, world size) when torchrun started this process (environment RANK and WORLD_SIZE), else (0, 1)."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    return (int(os.environ.get("RANK", "0")), world_size) if world_size > 1 else (0, 1)


def frame_counts(sources: Sequence[Path]) -> list[int]:
    """The camera frames of each demonstration file, read from the files' summaries: 0 for one without frames, and
    for one whose summary cannot be read (its own extraction says what is wrong with it, or skips it)."""
    return [_frames_of(src) for src in sources]


def _frames_of(src: Path) -> int:
    try:
        summary = read_summary(src, KIND_DEMONSTRATION)
    except RecordingError:
        return 0
    return summary.n_steps if summary.has_frames else 0


def auto_workers(sources: Sequence[Path]) -> int:
    """Worker processes for `workers="auto"`: one per core, at most one per file and one per WORKER_MIN_FRAMES
    frames to extract (at least 1), so that a small job never pays for starting processes."""
    frames = sum(frame_counts(sources))
    workers = max(1, min(cpu_cores(), len(sources), frames // WORKER_MIN_FRAMES))
    log.info(
        "--workers auto: %d worker(s) for %d file(s), %d frames on %d cores", workers, len(sources), frames, cpu_cores()
    )
    return workers


def extract_in_processes(
    jobs: Sequence[tuple[Path, Path, int]],
    keys: Sequence[int],
    extractor: Callable[[], FeatureExtractor],
    config: ExtractConfig,
    workers: int,
    bar: tqdm,
    failed: Callable[[Path, Exception], None],
) -> dict[int, Extracted]:
    """Extract `jobs` (source, output, its frames) in `workers` spawned processes sharing the cores; returns
    {key: Extracted}.

    Every worker receives this process's extractor (calibrated once, here), so all files share one
    identity, and builds its own backend with `inference_threads(config.threads, workers)` threads.
    A file that fails goes to `failed(source, error)`, which raises or records it (keep_going).
    """
    workers = min(workers, len(jobs))
    threads = inference_threads(config.threads, workers)
    with_frames = any(frames for _, _, frames in jobs)
    shared = extractor() if with_frames else None  # motion-only inputs need no network
    done = {}
    with (
        thread_environment(threads),
        process_pool(
            workers, initializer=_set_worker_extractor, initargs=(shared, threads, Views(config.views, config.seed))
        ) as pool,
    ):
        futures = {
            pool.submit(_extract_in_worker, src, dst): (key, src, frames) for key, (src, dst, frames) in zip(keys, jobs)
        }
        for future in as_completed(futures):
            key, src, frames = futures[future]
            try:
                item = future.result()  # a worker's error (a corrupt frame) is raised here, naming its file
            except (RecordingError, PerceptionError) as exc:
                failed(src, exc)
                continue
            done[key] = item
            bar.update(frames)
    return done


_WORKER: list[tuple[FeatureExtractor | None, Views]] = []  # the extractor and views a worker process was given


def _set_worker_extractor(extractor: FeatureExtractor | None, threads: int, views: Views) -> None:
    if extractor is not None:
        extractor.threads = threads  # this worker's share of the cores
    _WORKER.append((extractor, views))


def _extract_in_worker(src: Path, dst: Path) -> Extracted:
    extractor, views = _WORKER[0]
    return extract_file(src, dst, lambda: extractor, views=views)


def build_extractor(config: ExtractConfig, sources: Sequence[Path]) -> FeatureExtractor:
    """The configured extractor; random weights are calibrated, and int8 quantised, on frames sampled from `sources`."""
    if config.offline and config.weights == "imagenet":
        find_imagenet_weights(download=False)  # refuses here, naming the cache and the alternatives
    extractor = FeatureExtractor(
        config.weights,
        backend=config.backend,
        threads=inference_threads(config.threads),
        batch_size=config.batch_size,
        seed=config.seed,
        precision=config.precision,
    )
    frames = None
    if extractor.needs_calibration:
        with heartbeat(f"reading frames from {len(sources)} file(s) to calibrate random weights", config.quiet):
            frames = calibration_frames(sources, CALIBRATION_FRAMES)
        desc = f"calibrating random weights on {len(frames)} frames"
        with progress_bar(total=len(frames), desc=desc, unit="frame", quiet=config.quiet) as bar:
            extractor.calibrate(frames, done=bar.update)
    if extractor.needs_quantisation:
        if frames is None:
            with heartbeat(f"reading frames from {len(sources)} file(s) to quantise to int8", config.quiet):
                frames = calibration_frames(sources, CALIBRATION_FRAMES)
        extractor.quantise(frames)
    return extractor


def extract_file(
    src: Path,
    dst: Path,
    extractor: Callable[[], FeatureExtractor],
    bar: tqdm | None = None,
    views: Views | None = None,
) -> Extracted:
    """Extract demonstration file `src` into trajectory file `dst` (atomic); `extractor()` gives the network, and
    `views` the views of the frames whose features the file also holds."""
    demo = read_demonstration(src)
    if demo.frames is None:
        log.info("%s has no frames: writing a motion-only trajectory", src)
        with in_file(src):  # a record's checks name its episode id: the file is what the user knows
            trajectory = Trajectory.from_demonstration(demo)
    else:
        extractor().prepare()
        if bar is not None and bar.n == 0:
            bar.reset(total=bar.total)  # frames/s and the time left from here: the backend's set-up is done
        features = features_of_frames(demo.frames, extractor(), src, bar)  # (T, 1280)
        drawn = [] if views is None else views.of(demo.episode.episode_id)
        seen = [features_of_frames(demo.frames, extractor(), src, bar, view) for view in drawn]  # each (T, 1280)
        with in_file(src):
            trajectory = Trajectory.from_demonstration(
                demo, features, extractor().identity, views=np.stack(seen) if seen else None
            )
    with output_file(dst) as staged:
        write_trajectory(staged, trajectory)
    log.info("%s -> %s (%d steps)", src, dst, demo.n_steps)
    return Extracted(src, dst, demo.n_steps, skipped=False)


def features_of_frames(
    frames: Sequence[bytes], extractor: FeatureExtractor, src: Path, bar: tqdm | None = None, view: View | None = None
) -> np.ndarray:
    """Features of JPEG frames (under `view`, perception.views): (T, 1280) float32. Decoding of the next batch
    overlaps inference of this one."""
    out = np.empty((len(frames), FEATURE_DIM), dtype=np.float32)  # (T, 1280)
    starts = range(0, len(frames), extractor.batch_size)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="decode") as pool:  # OpenCV releases the GIL
        pending = pool.submit(decode_batch, frames, 0, extractor.batch_size, src)
        for start in starts:
            pixels = pending.result()  # (B, 224, 224, 3) uint8
            if start + extractor.batch_size < len(frames):
                pending = pool.submit(decode_batch, frames, start + extractor.batch_size, extractor.batch_size, src)
            if view is not None:
                pixels = view.apply(pixels, start)
            out[start : start + len(pixels)] = extractor.features(pixels)
            if bar is not None:
                bar.update(len(pixels))
    return out


def decode_batch(frames: Sequence[bytes], start: int, size: int, src: Path) -> np.ndarray:
    """Decode and resize frames[start:start+size] -> (B, 224, 224, 3) uint8; a corrupt frame names file and step."""
    decoded = []
    for step in range(start, min(start + size, len(frames))):
        try:
            decoded.append(resize_frames(decode_image(frames[step])[None])[0])  # (224, 224, 3)
        except PerceptionError as exc:
            raise PerceptionError(
                f"{src}: step {step} on {TOPIC_IMAGE}: {exc}; the frame is corrupt: re-ingest "
                f"the recording from its source"
            ) from None
    return np.stack(decoded)


def calibration_frames(sources: Sequence[Path], count: int) -> np.ndarray:
    """Up to `count` frames spread evenly over the demonstrations in `sources` (sorted by path): (N, 224, 224, 3) uint8.

    Sorting makes the calibration, hence the weights hash, independent of the order inputs were given in. Which
    files have frames, and how many, comes from their summaries; then one file at a time is read for its share.
    """
    with_frames = []
    for src in sorted(sources):
        summary = read_summary(src, KIND_DEMONSTRATION)
        if summary.has_frames:
            with_frames.append((src, summary.n_steps))
    if not with_frames:
        raise PipelineError(
            "random weights are calibrated on the recordings' frames, but no input has frames; "
            "give demonstrations with a camera topic, or use --weights imagenet or a weights file"
        )
    per_file = math.ceil(count / len(with_frames))
    frames: list[np.ndarray] = []
    for src, steps in with_frames:
        if len(frames) >= count:
            break
        jpegs = read_demonstration(src).frames or []
        for step in np.linspace(0, steps - 1, min(per_file, steps)).round().astype(int):
            frames.append(decode_batch(jpegs, int(step), 1, src))  # (1, 224, 224, 3)
    return np.concatenate(frames[:count])  # (N, 224, 224, 3)


def up_to_date_steps(src: Path, dst: Path, extractor: Callable[[], FeatureExtractor], views: int = 0) -> int | None:
    """Step count of `dst` if it is newer than `src` and its features come from an extractor compatible with ours,
    under `views` views, read from its summary alone (`recordings.read_summary`)."""
    if not dst.is_file() or dst.stat().st_mtime < src.stat().st_mtime:
        return None
    try:
        summary = read_summary(dst, KIND_TRAJECTORY)  # its metadata only: a few small reads, whatever its size
    except RecordingError as exc:  # not a readable trajectory: refused unless --force, or redone if stale
        log.debug("%s is not an up-to-date trajectory file: %s", dst, exc)
        return None
    if not summary.extractor:  # motion-only: its source had no frames, and the source did not change
        return summary.n_steps
    same = compatibility_key(summary.extractor) == compatibility_key(extractor().identity)
    return summary.n_steps if same and summary.views == views else None


def plan_outputs(inputs: Sequence[Path], out: Path) -> list[tuple[Path, Path]]:
    """(demonstration file, trajectory file) pairs; raises PipelineError for missing inputs and clashing outputs."""
    pairs: list[tuple[Path, Path]] = []
    for given in inputs:
        pairs += [
            (p, out / (p.relative_to(given) if given.is_dir() else p.name)) for p in mcap_files(given, DEMONSTRATIONS)
        ]
    sources: dict[Path, Path] = {}
    for src, dst in pairs:
        if dst.resolve() == src.resolve():
            raise PipelineError(f"{src}: the output would overwrite this input; choose another --out folder")
        if dst.resolve() in sources:
            raise PipelineError(
                f"{sources[dst.resolve()]} and {src} would both be written to {dst}; extract them "
                f"into different --out folders"
            )
        sources[dst.resolve()] = src
    inputs_resolved = {src.resolve() for src, _ in pairs}
    for dst in sources:
        if dst in inputs_resolved:
            raise PipelineError(
                f"{dst} is an input and would be overwritten by another input's output; choose another --out folder"
            )
    return pairs
