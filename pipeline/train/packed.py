"""The training columns of a process's share of the files, packed into one memory-mapped float32 file.

    packed = pack_columns(data, indices, layout, work / "columns-0-of-1")   # columns-0-of-1.npy + .json
    TrajectoryStack.from_rows(packed.rows, *packed.span(part), model)

Each trajectory file is read once (its camera frames left unparsed, `read_trajectory(frames=False)`; a few files at
a time on threads, one per core: decompressing, checking and hashing release the GIL), the layout's columns
(`TrainingColumns.select`) are appended to `<name>.npy` (float32, the files' own values, one file after another) and
dropped; `<name>.json` records which files, with their sha256 and the sha256 of their packed rows. The
training then maps the file read-only: the rows live in the page cache, shared with any other process mapping them,
and a batch reads only the rows it draws (models.sampler). A resumed run whose files and columns did not change
maps the pack it wrote before instead of reading the files again.

A file holding views of its features (perception.views) packs each view's rows after its own, the feature block
replaced by the view's: `span` gives the files' own rows, `seen` those and every view's, the rows a model trains on.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from cnep.models.normaliser import Moments
from cnep.outputs import staged
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.data import TrainingFile, TrainingSet
from cnep.pipeline.train.presets import TrainingColumns
from cnep.pipeline.workers import cpu_cores
from cnep.recordings import read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES
from cnep.runtime.manifest import file_sha256

log = logging.getLogger(__name__)

PACK_VERSION = 1
READ_AHEAD = 4  # files read ahead of the writer per thread
DTYPE = np.dtype("<f4")  # the files' own float32: batches read exactly the values a file holds


@dataclass(frozen=True)
class PackedColumns:
    """Files `indices` (of the training set) packed: rows (R, width) float32 read-only memory map, each file's first
    row, steps and views (starts, lengths, views: (n,) int64, in `indices` order; a file's views follow its own
    rows), its sha256 and the sha256 of its packed rows."""

    indices: tuple[int, ...]
    rows: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    views: np.ndarray
    sha256: tuple[str, ...]
    digests: tuple[str, ...]

    def span(self, part: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """(starts, lengths) of training-set files `part` (each one of `indices`), in `part`'s order: their own
        rows."""
        at = {index: k for k, index in enumerate(self.indices)}
        order = [at[index] for index in part]
        return self.starts[order], self.lengths[order]

    def seen(self, part: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """(starts, lengths) of the rows of files `part` and of each of their views, file by file in `part`'s
        order."""
        at = {index: k for k, index in enumerate(self.indices)}
        order = [at[index] for index in part]
        starts = [self.starts[k] + v * self.lengths[k] for k in order for v in range(1 + self.views[k])]
        lengths = [self.lengths[k] for k in order for _ in range(1 + self.views[k])]
        return np.array(starts, dtype=np.int64), np.array(lengths, dtype=np.int64)

    def held(self, part: Sequence[int], holds: Mapping[int, int], views: bool = True) -> np.ndarray:
        """(N,) int64 the steps each trajectory of `seen(part)` (`views`) or `span(part)` is held at its last row:
        its file's in `holds` (training-set index -> steps; 0 where not in it)."""
        at = {index: k for k, index in enumerate(self.indices)}
        copies = [1 + int(self.views[at[i]]) if views else 1 for i in part]
        return np.repeat(np.array([holds.get(i, 0) for i in part], dtype=np.int64), copies)

    def columns(self, part: Sequence[int], span: tuple[int, int]) -> dict[int, np.ndarray]:
        """Training-set index -> the values (T, b - a) on model columns `span` (a, b) of each of files `part`."""
        starts, lengths = self.span(part)
        a, b = span
        return {i: np.array(self.rows[s : s + n, a:b]) for i, s, n in zip(part, starts.tolist(), lengths.tolist())}

    def moments(self, part: Sequence[int], co: Sequence[int] = ()) -> Moments:
        """The normaliser's moments of the rows files `part` train on (`seen`), file by file (float64, one file's
        rows converted at a time), with the scatter matrix of model columns `co` (`CNEPConfig.projected_columns`)."""
        starts, lengths = self.seen(part)
        return Moments.total(Moments.of(self.rows[a : a + n], co) for a, n in zip(starts.tolist(), lengths.tolist()))


def pack_columns(data: TrainingSet, indices: Sequence[int], layout: TrainingColumns, base: Path) -> PackedColumns:
    """Files `indices` of `data` packed at `base` + ".npy" / ".json" (written unless an identical pack is there)."""
    files = [data.files[i] for i in indices]
    with ThreadPoolExecutor(cpu_cores(), thread_name_prefix="pack") as pool:
        sha256 = list(pool.map(lambda f: file_sha256(f.path), files))
    index = {
        "pack_version": PACK_VERSION,
        "dtype": DTYPE.str,
        "columns": [list(span) for span in layout.columns],
        "files": [{"path": str(f.path.resolve()), "sha256": h} for f, h in zip(files, sha256)],
    }
    table, rows_file = base.with_suffix(".json"), base.with_suffix(".npy")
    digests = _reusable(table, rows_file, index)
    if digests is None:
        with staged(record=True) as staging:  # renamed and recorded together: a stopped run's folder may be removed
            with staging.open(rows_file) as stream:
                digests = _write(files, layout, stream)
            staging.write(table, json.dumps({**index, "digests": digests}).encode())
    else:
        log.info("%s: the columns of these %d files are packed already", rows_file, len(files))
    lengths = np.array([f.n_steps for f in files], dtype=np.int64)
    views = np.array([f.views for f in files], dtype=np.int64)
    packed = lengths * (1 + views)  # each file's rows with its views'
    return PackedColumns(
        indices=tuple(indices),
        rows=np.load(rows_file, mmap_mode="r"),
        starts=np.concatenate([[0], np.cumsum(packed)[:-1]]).astype(np.int64),
        lengths=lengths,
        views=views,
        sha256=tuple(sha256),
        digests=tuple(digests),
    )


def _reusable(table: Path, rows_file: Path, index: dict) -> list[str] | None:
    """The row digests of the pack at `table`, `rows_file` if it was written for `index`, else None."""
    try:
        saved = json.loads(table.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not rows_file.is_file() or {k: v for k, v in saved.items() if k != "digests"} != index:
        return None
    return saved["digests"]


def _write(files: Sequence[TrainingFile], layout: TrainingColumns, stream: IO[bytes]) -> list[str]:
    """Write each file's layout columns to `stream` as one .npy array; returns the sha256 of each file's rows."""
    width, total = sum(b - a for a, b in layout.columns), sum(f.n_steps * (1 + f.views) for f in files)
    digests = []
    threads = cpu_cores()
    with ThreadPoolExecutor(threads, thread_name_prefix="pack") as pool:
        header = {"descr": DTYPE.str, "fortran_order": False, "shape": (total, width)}
        np.lib.format.write_array_header_1_0(stream, header)
        for start in range(0, len(files), READ_AHEAD * threads):  # a few files in memory at a time
            for rows, digest in pool.map(lambda f: _rows(f, layout), files[start : start + READ_AHEAD * threads]):
                stream.write(rows)
                digests.append(digest)
    return digests


def _rows(f: TrainingFile, layout: TrainingColumns) -> tuple[bytes, str]:
    """File `f`'s layout columns as float32 bytes, then each view's, and their sha256."""
    trajectory = read_trajectory(f.path, frames=False)
    views = () if trajectory.views is None else trajectory.views  # (V, T, feature width)
    if trajectory.width != layout.recording_width or trajectory.n_steps != f.n_steps or len(views) != f.views:
        raise PipelineError(
            f"{f.path}: holds {trajectory.n_steps} steps of {trajectory.width} columns and {len(views)} views, its "
            f"summary says {f.n_steps} of {layout.recording_width} and {f.views}; the file changed while training "
            f"started"
        )
    tables = [trajectory.data]  # (T, recording width) each: its own, then each view's
    for view in views:
        a, b = trajectory.blocks[BLOCK_FEATURES]
        seen = trajectory.data.copy()
        seen[:, a:b] = view
        tables.append(seen)
    rows = b"".join(np.ascontiguousarray(layout.select(table), dtype=DTYPE).tobytes() for table in tables)
    return rows, hashlib.sha256(rows).hexdigest()
