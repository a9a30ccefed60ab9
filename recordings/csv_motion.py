"""Pose and gripper tables from CSV files, with a configurable column mapping.

Header names are matched after stripping spaces and underscores at both ends, so the Baxter
recordings' padded `________p_x________` matches `p_x`. The default mapping reads the Baxter format
(`Time` in ms since the start of the recording, `p_x p_y p_z`, `q_x q_y q_z q_w`,
`gripper_position`); other columns are ignored. A UTF-8 byte-order mark is skipped, and a file whose
header is separated by semicolons is read as such, with decimal commas.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from cnep.recordings.errors import RecordingError

NS_PER_UNIT = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}


@dataclass(frozen=True)
class CsvColumns:
    """Which CSV column holds what. `gripper=""` means no gripper column (recorded as 0.0)."""

    time: str = "Time"
    time_unit: str = "ms"  # one of NS_PER_UNIT
    x: str = "p_x"
    y: str = "p_y"
    z: str = "p_z"
    qx: str = "q_x"
    qy: str = "q_y"
    qz: str = "q_z"
    qw: str = "q_w"
    gripper: str = "gripper_position"

    def __post_init__(self) -> None:
        if self.time_unit not in NS_PER_UNIT:
            raise RecordingError(
                f"CSV column mapping: time_unit {self.time_unit!r} is not one of {sorted(NS_PER_UNIT)}"
            )

    @classmethod
    def from_overrides(cls, overrides: Mapping[str, str]) -> CsvColumns:
        """The Baxter defaults with some keys replaced, e.g. {"time": "stamp", "time_unit": "s"}."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise RecordingError(f"CSV column mapping: unknown keys {unknown}; known keys are {sorted(known)}")
        return replace(cls(), **overrides)


@dataclass(eq=False)
class MotionTable:
    """Rows of a motion CSV: timestamps_ns int64 (N,), pose float64 (N, 7) with unit quaternions, gripper (N,)."""

    path: Path
    timestamps_ns: np.ndarray
    pose: np.ndarray
    gripper: np.ndarray


def sniff_delimiter(text: str) -> str:
    """`;` if the header line (the first non-blank one) splits on semicolons rather than commas, else `,`."""
    header = next((line for line in text.splitlines() if line.strip()), "")
    return ";" if header.count(";") > header.count(",") else ","


def _normalise(name: str) -> str:
    return name.strip().strip("_").strip()


def read_motion_csv(path: str | os.PathLike, columns: CsvColumns = CsvColumns()) -> MotionTable:
    """Read a motion CSV; every problem is a RecordingError naming the file, line and column."""
    p = Path(path)
    try:
        with open(p, newline="", encoding="utf-8-sig") as f:  # a byte-order mark (Excel's UTF-8 CSV) is skipped
            text = f.read()
        delimiter = sniff_delimiter(text)
        reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
        numbered = [(n, row) for n, row in enumerate(reader, start=1) if any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise RecordingError(f"{p}: cannot read as CSV ({exc})") from None
    if delimiter == ";":  # the European convention: decimal commas
        numbered = [(n, [cell.replace(",", ".") for cell in row]) for n, row in numbered]
    lines = [n for n, _ in numbered]  # file line number of each kept row (blank lines skipped)
    rows = [row for _, row in numbered]
    if len(rows) < 3:
        found = "no rows" if not rows else f"a header and {len(rows) - 1} data row{'s' if len(rows) != 2 else ''}"
        raise RecordingError(
            f"{p}: needs a header row and at least 2 data rows, found {found}; a demonstration "
            f"needs at least 2 time steps"
        )
    header = [_normalise(h) for h in rows[0]]
    wanted = [columns.time, columns.x, columns.y, columns.z, columns.qx, columns.qy, columns.qz, columns.qw]
    if columns.gripper:
        wanted.append(columns.gripper)
    missing = [w for w in wanted if _normalise(w) not in header]
    if missing:
        raise RecordingError(
            f"{p}: missing CSV columns {missing} (header: {header}); map them with --column KEY=NAME "
            f"(keys: {[f.name for f in fields(CsvColumns) if f.name != 'time_unit']})"
        )
    index = [header.index(_normalise(w)) for w in wanted]
    values = np.empty((len(rows) - 1, len(index)), dtype=np.float64)  # (N, 8 or 9)
    for r, row in enumerate(rows[1:]):
        for c, col in enumerate(index):
            try:
                values[r, c] = float(row[col])
            except (IndexError, ValueError):
                cell = row[col] if col < len(row) else "<missing>"
                raise RecordingError(
                    f"{p}: line {lines[r + 1]}, column {wanted[c]!r}: {cell!r} is not a number"
                ) from None
    bad = ~np.isfinite(values)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise RecordingError(f"{p}: line {lines[r + 1]}, column {wanted[c]!r} is {values[r, c]} (NaN or infinite)")
    ts = np.round(values[:, 0] * NS_PER_UNIT[columns.time_unit]).astype(np.int64)  # (N,)
    back = np.diff(ts) <= 0
    if back.any():
        r = int(np.flatnonzero(back)[0]) + 1
        raise RecordingError(
            f"{p}: time goes backwards (or repeats) at line {lines[r + 1]} "
            f"({values[r - 1, 0]} then {values[r, 0]} {columns.time_unit})"
        )
    if ts[0] < 0:
        raise RecordingError(f"{p}: negative time {values[0, 0]} {columns.time_unit} on line {lines[1]}")
    quat = values[:, 4:8]  # (N, 4)
    norm = np.linalg.norm(quat, axis=1)
    if (norm < 1e-6).any():
        r = int(np.flatnonzero(norm < 1e-6)[0])
        raise RecordingError(f"{p}: line {lines[r + 1]}: the quaternion has zero length")
    pose = np.concatenate([values[:, 1:4], quat / norm[:, None]], axis=1)  # (N, 7)
    gripper = values[:, 8] if columns.gripper else np.zeros(len(ts))
    return MotionTable(path=p, timestamps_ns=ts, pose=pose, gripper=gripper)
