"""Stage `ingest`: raw recordings -> one demonstration MCAP file per demonstration.

Sources found under SRC (a file or a folder, searched recursively, in sorted order):
- a folder holding a video (MP4/AVI/MOV/MKV) or numbered images, plus one CSV -> one demonstration;
- any other CSV -> one motion-only demonstration (the Baxter format works without options);
- an MCAP file -> one demonstration from its Foxglove image/pose/gripper topics;
- a ROS 1 `.bag` file or a ROS 2 bag folder (`metadata.yaml`) -> one demonstration (same topics as MCAP);
- a LeRobot dataset folder (`meta/info.json`, codebase v2.1 or v3.0; SRC itself or a sub-folder) -> one
  demonstration per episode, all episodes read and checked before the first file is written.
Each is written to OUT/<path relative to SRC>.mcap (atomically, under the lock of OUT); SRC is only read.
Every frame is checked to decode. An output is skipped when it is up to date: complete, newer than its
source and made with the same options (their digest is in its episode metadata, `ingest_options`), so a
run stopped half-way finishes when run again; one older than its source is redone; any other existing
output is refused unless `force`, which replaces only demonstration files cnep wrote (pipeline.contract).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from tqdm.contrib.logging import logging_redirect_tqdm

from cnep.outputs import output_file, output_lock, writing_as
from cnep.pipeline.contract import output_folder, raise_if_skipped, refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import SUFFIX, coerce_paths
from cnep.pipeline.progress import progress_bar
from cnep.recordings import FORMAT_VERSION, Demonstration, DemonstrationReader, RecordingError, write_demonstration
from cnep.recordings.adapters import FrameTiming, demonstration_from_csv, demonstration_from_folder, media_of
from cnep.recordings.csv_motion import CsvColumns
from cnep.recordings.lerobot import LerobotMapping, demonstration_from_lerobot, is_lerobot_dataset, plan_lerobot
from cnep.recordings.mcap_source import McapTopics, demonstration_from_mcap
from cnep.recordings.media import check_decodable
from cnep.recordings.plausibility import checked
from cnep.recordings.rosbag import demonstration_from_rosbag, is_ros2_bag

log = logging.getLogger(__name__)

SOURCE_ERRORS = (RecordingError, PipelineError)  # what one bad source can raise (skipped by keep_going)

OPTIONS_KEY = "ingest_options"  # episode metadata: the options_digest of the run that wrote the file
FILE_KINDS = {".csv": "csv", SUFFIX: "mcap", ".bag": "rosbag"}
FORMATS = ("auto", "lerobot")  # auto: a LeRobot dataset if SRC has meta/info.json, else files as found


@dataclass(frozen=True)
class IngestConfig:
    """src: file or folder to read; out: folder to write (created if missing, never inside src).

    force: replace existing demonstration files; keep_going: skip sources that fail and report them at the end.
    """

    src: Path
    out: Path
    columns: CsvColumns = field(default_factory=CsvColumns)
    timing: FrameTiming = field(default_factory=FrameTiming)
    topics: McapTopics = field(default_factory=McapTopics)
    task: str = ""
    force: bool = False
    keep_going: bool = False
    quiet: bool = False
    format: str = "auto"  # one of FORMATS
    lerobot: LerobotMapping = field(default_factory=LerobotMapping)

    def __post_init__(self) -> None:
        coerce_paths(self)


@dataclass(frozen=True)
class Source:
    kind: str  # "folder", "csv", "mcap", "rosbag" or "lerobot"
    path: Path
    episode_id: str  # path relative to src, without suffix ("/"-separated)
    plan: object = None  # "lerobot": the episode, read and checked (recordings.lerobot.LerobotEpisode)


@dataclass(frozen=True)
class Ingested:
    source: Source
    output: Path
    n_steps: int
    has_frames: bool
    fps: float
    skipped: bool = False  # up to date: left as it was


def _episode_id(src: Path, path: Path, strip_suffix: bool) -> str:
    rel = path.relative_to(src) if path != src else Path(src.name)
    if strip_suffix:
        rel = rel.with_suffix("")
    return rel.as_posix() if rel.parts else src.resolve().name


def discover(src: Path, fmt: str = "auto", lerobot: LerobotMapping = LerobotMapping()) -> list[Source]:
    """Every demonstration source under `src` (see the module docstring); `fmt` one of FORMATS."""
    if fmt not in FORMATS:
        raise RecordingError(f"format {fmt!r} is not one of {list(FORMATS)}")
    if not src.exists():
        raise RecordingError(f"{src}: no such file or folder")
    if fmt == "lerobot" or (fmt == "auto" and src.is_dir() and is_lerobot_dataset(src)):
        return [Source("lerobot", src, episode.episode_id, episode) for episode in plan_lerobot(src, lerobot)]
    if src.is_file():
        kind = FILE_KINDS.get(src.suffix.lower())
        if kind is None:
            raise RecordingError(
                f"{src}: cannot ingest a {src.suffix or 'suffix-less'} file; give a CSV, an MCAP, a ROS "
                f".bag or a folder"
            )
        return [Source(kind, src, src.stem)]
    found: list[Source] = []
    whole: list[Path] = []  # ROS 2 bags and LeRobot datasets: the files inside are not sources of their own
    for folder in sorted([src, *(d for d in src.rglob("*") if d.is_dir())]):
        if any(folder.is_relative_to(done) for done in whole):
            continue
        if is_ros2_bag(folder):
            whole.append(folder)
            found.append(Source("rosbag", folder, _episode_id(src, folder, strip_suffix=False)))
            continue
        if fmt == "auto" and is_lerobot_dataset(folder):  # a dataset in a sub-folder: OUT/<sub-folder>/episode_...
            whole.append(folder)
            prefix = _episode_id(src, folder, strip_suffix=False)
            found += [Source("lerobot", folder, f"{prefix}/{e.episode_id}", e) for e in plan_lerobot(folder, lerobot)]
            continue
        videos, images = media_of(folder)
        if videos or images:
            found.append(Source("folder", folder, _episode_id(src, folder, strip_suffix=False)))
            continue
        for f in sorted(folder.iterdir()):
            kind = FILE_KINDS.get(f.suffix.lower()) if f.is_file() else None
            if kind:
                found.append(Source(kind, f, _episode_id(src, f, strip_suffix=True)))
    if not found:
        raise RecordingError(
            f"{src}: no recordings found (looked for CSV, MCAP and ROS bag files, ROS 2 bag folders, and "
            f"folders with a video or images)"
        )
    return found


def load(source: Source, config: IngestConfig) -> Demonstration:
    """The demonstration of one source; a RecordingError names the source (a record's own check names only its
    episode id)."""
    try:
        return _load(source, config)
    except RecordingError as exc:
        if str(exc).startswith(str(source.path)) or str(exc).startswith(str(source.path.parent)):
            raise
        raise RecordingError(f"{source.path}: {exc}") from None


def _load(source: Source, config: IngestConfig) -> Demonstration:
    if source.kind == "folder":
        return demonstration_from_folder(source.path, source.episode_id, config.columns, config.timing, config.task)
    if source.kind == "csv":
        return demonstration_from_csv(source.path, source.episode_id, config.columns, config.task)
    if source.kind == "rosbag":
        return demonstration_from_rosbag(source.path, source.episode_id, config.topics, config.task)
    if source.kind == "lerobot":
        return demonstration_from_lerobot(source.plan, config.task)
    return demonstration_from_mcap(source.path, source.episode_id, config.topics, config.task)


@writing_as("ingest")
def ingest(config: IngestConfig) -> list[Ingested]:
    """Convert every source under `config.src`; returns what was written, in source order.

    Existing outputs are refused unless `config.force`; a source that fails stops the run (nothing of
    it is written) unless `config.keep_going`, which skips it and ends with one PipelineError naming
    every skipped source (pipeline.contract).
    """
    src, out = Path(config.src), Path(config.out)
    sources = discover(src, config.format, config.lerobot)
    if src.is_dir():
        refuse_inputs([out], [src], what="the output folder", whole=False)
    targets = [out / f"{source.episode_id}{SUFFIX}" for source in sources]
    for source, target in zip(sources, targets):
        if target.resolve() == source.path.resolve():
            raise RecordingError(f"{target}: the output would replace its input; choose another --out folder")
    options = options_digest(config)
    done, skipped = [], []
    with output_folder(out), output_lock(out, folder=True), logging_redirect_tqdm():
        current = {t: None if config.force else up_to_date(s, t, options) for s, t in zip(sources, targets)}
        stale = {t for s, t in zip(sources, targets) if current[t] is None and _older_than_source(t, s)}
        refuse_existing(
            [t for t in targets if current[t] is None and t not in stale],
            config.force,
            "demonstration file",
            " and is not this source's demonstration file from these options",
        )
        refuse_existing(sorted(stale), True)  # redone without --force, but only if cnep wrote it
        for source, target in zip(progress_bar(sources, desc="ingest", unit="demo", quiet=config.quiet), targets):
            if current[target] is not None:
                log.info("%s is up to date, skipped", target)
                done.append(current[target])
                continue
            try:
                demo = checked(load(source, config), str(source.path))
                if source.kind != "folder":  # a folder's images are checked (or re-encoded) as they are read
                    check_decodable(demo.frames, str(source.path))
            except SOURCE_ERRORS as exc:
                if not config.keep_going:
                    raise
                log.warning("skipped %s: %s", source.path, exc)
                skipped.append(str(exc))
                continue
            demo.episode = replace(demo.episode, extra={**demo.episode.extra, OPTIONS_KEY: options})
            target.parent.mkdir(parents=True, exist_ok=True)  # inside `out`, which we could create
            with output_file(target) as staged:
                write_demonstration(staged, demo)
            kind = "frames" if demo.has_frames else "motion-only"
            origin = source.path if source.plan is None else f"{source.path} ({source.episode_id})"
            log.info("%s -> %s: %d steps, %s, %.1f Hz", origin, target, demo.n_steps, kind, demo.episode.fps)
            done.append(Ingested(source, target, demo.n_steps, demo.has_frames, demo.episode.fps))
    raise_if_skipped(skipped, len(sources), f"were written to {out}")
    return done


def options_digest(config: IngestConfig) -> str:
    """sha256 (16 hex digits) of every option that shapes a demonstration file, stored in its episode metadata."""
    shaping = {
        "columns": asdict(config.columns),
        "timing": asdict(config.timing),
        "topics": asdict(config.topics),
        "task": config.task,
        "format": config.format,
        "lerobot": asdict(config.lerobot),
        "format_version": FORMAT_VERSION,
    }
    return hashlib.sha256(json.dumps(shaping, sort_keys=True, default=str).encode()).hexdigest()[:16]


def source_mtime(source: Source) -> float:
    """When the source last changed: its file's time, or the newest file in its folder (a bag, a dataset: all below)."""
    path = source.path
    if path.is_file():
        return path.stat().st_mtime
    files = path.iterdir() if source.kind == "folder" else path.rglob("*")
    return max((f.stat().st_mtime for f in files if f.is_file()), default=path.stat().st_mtime)


def _older_than_source(target: Path, source: Source) -> bool:
    """True if `target` is a file older than its source (a stale output, redone without --force)."""
    return target.is_file() and target.stat().st_mtime < source_mtime(source)


def up_to_date(source: Source, target: Path, options: str) -> Ingested | None:
    """What `target` holds if it is complete (every CRC valid), newer than `source` and made with these options."""
    if not target.is_file() or _older_than_source(target, source):
        return None
    try:
        with DemonstrationReader(target) as reader:
            if reader.episode.extra.get(OPTIONS_KEY) != options:
                return None
            demo = reader.read()
    except RecordingError as exc:  # not a complete demonstration file: refused unless --force, or redone if stale
        log.debug("%s is not an up-to-date demonstration file: %s", target, exc)
        return None
    return Ingested(source, target, demo.n_steps, demo.has_frames, demo.episode.fps, skipped=True)


def run(config: IngestConfig) -> Path:
    """Stage entry point: ingest everything and return the output folder."""
    ingest(config)
    return Path(config.out)
