"""Pose and gripper tables from CSV files, with the columns found by their usual names or mapped by hand.

Header names are matched without case and after stripping spaces and underscores at both ends, so the
Baxter recordings' padded `________p_x________` matches `p_x`. Each key accepts its usual names
(`ACCEPTED_NAMES`: `t`/`time`/`timestamp`, `x y z` or `p_x p_y p_z`, `qx qy qz qw` or `q_x ...`,
`gripper` or `gripper_position`), so the Baxter format and a plain `t,x,y,z,qx,qy,qz,qw,gripper` both
work without options; `CsvColumns` pins a key to one column. The unit of time is stated (`time_unit`),
named in the header (`time_ms`, `t [s]`) or inferred from the step rate it gives, and said in the log
and in the recording's metadata (`MotionTable.notes`). Other columns are ignored. A UTF-8 byte-order
mark is skipped, and a file whose header is separated by semicolons is read as such, with decimal commas.
"""

from __future__ import annotations

import csv
import io
import logging
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from cnep.recordings.errors import RecordingError
from cnep.recordings.validation import unit_quaternions

log = logging.getLogger(__name__)

NS_PER_UNIT = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
NS_PER_S = 1e9
# The usual names of each column (matched without case, padding underscores stripped), first match wins.
ACCEPTED_NAMES: Mapping[str, tuple[str, ...]] = {
    "time": ("time", "t", "timestamp", "stamp"),
    "x": ("p_x", "x", "pos_x", "position_x"),
    "y": ("p_y", "y", "pos_y", "position_y"),
    "z": ("p_z", "z", "pos_z", "position_z"),
    "qx": ("q_x", "qx", "quat_x", "orientation_x"),
    "qy": ("q_y", "qy", "quat_y", "orientation_y"),
    "qz": ("q_z", "qz", "quat_z", "orientation_z"),
    "qw": ("q_w", "qw", "quat_w", "orientation_w"),
    "gripper": ("gripper_position", "gripper"),
}
_UNIT_IN_NAME = re.compile(r"^(?P<name>.+?)[\s_]*[\[(]?(?P<unit>s|ms|us|ns)[\])]?$")
# Step rates a robot recording has (Hz): outside them a stated time unit is refused; inside, an unstated one is
# chosen with its rate nearest (in ratio) to TYPICAL_RATE_HZ.
PLAUSIBLE_RATE_HZ = (0.1, 10_000.0)
TYPICAL_RATE_HZ = 50.0


@dataclass(frozen=True)
class CsvColumns:
    """Which CSV column holds what: a header name per key, or None for any of the key's ACCEPTED_NAMES.

    `gripper=""` means no gripper column (recorded as 0.0); `time_unit` None: named in the time column's
    header (`time_ms`) or inferred from the step rate.
    """

    time: str | None = None
    time_unit: str | None = None  # one of NS_PER_UNIT
    x: str | None = None
    y: str | None = None
    z: str | None = None
    qx: str | None = None
    qy: str | None = None
    qz: str | None = None
    qw: str | None = None
    gripper: str | None = None

    def __post_init__(self) -> None:
        if self.time_unit is not None and self.time_unit not in NS_PER_UNIT:
            raise RecordingError(
                f"CSV column mapping: time_unit {self.time_unit!r} is not one of {sorted(NS_PER_UNIT)}"
            )

    @classmethod
    def from_overrides(cls, overrides: Mapping[str, str]) -> CsvColumns:
        """The usual names with some keys pinned, e.g. {"time": "stamp", "time_unit": "s"}."""
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(overrides) - set(known))
        if unknown:
            raise RecordingError(f"CSV column mapping: unknown keys {unknown}; the keys are {', '.join(known)}")
        return replace(cls(), **overrides)


@dataclass(eq=False)
class MotionTable:
    """Rows of a motion CSV: timestamps_ns int64 (N,), pose float64 (N, 7) with unit quaternions, gripper (N,)."""

    path: Path
    timestamps_ns: np.ndarray
    pose: np.ndarray
    gripper: np.ndarray
    notes: dict[str, str] = field(default_factory=dict)  # what was assumed, for the recording's metadata


def sniff_delimiter(text: str) -> str:
    """`;` if the header line (the first non-blank one) splits on semicolons rather than commas, else `,`."""
    header = next((line for line in text.splitlines() if line.strip()), "")
    return ";" if header.count(";") > header.count(",") else ","


def _normalise(name: str) -> str:
    return name.strip().strip("_").strip().lower()


def _find_columns(header: list[str], columns: CsvColumns, p: Path) -> tuple[list[str], list[int], str | None]:
    """(key of each wanted column, its index in `header`, the time unit the time column's name states)."""
    keys = [k for k in ACCEPTED_NAMES if not (k == "gripper" and columns.gripper == "")]
    found, missing, named_unit = [], [], None
    for key in keys:
        pinned = getattr(columns, key)
        names = (_normalise(pinned),) if pinned else ACCEPTED_NAMES[key]
        hits = [i for i, h in enumerate(header) if h in names]
        if not hits and key == "time" and not pinned:  # `time_ms`, `t [s]`: the name states the unit
            for i, h in enumerate(header):
                m = _UNIT_IN_NAME.match(h)
                if m and _normalise(m["name"]) in names:
                    hits, named_unit = [i], m["unit"]
                    break
        if len(hits) > 1:
            raise RecordingError(
                f"{p}: columns {[header[i] for i in hits]} could each be the {key!r} column; choose one with "
                f"--column {key}=NAME"
            )
        (found if hits else missing).append((key, hits[0] if hits else None))
    if missing:
        wanted = "; ".join(f"{k}: {getattr(columns, k) or ' or '.join(ACCEPTED_NAMES[k])}" for k, _ in missing)
        raise RecordingError(
            f"{p}: missing CSV columns ({wanted}); the header is {header}; map them with --column KEY=NAME "
            f"(keys: {', '.join(f.name for f in fields(CsvColumns))}; gripper= for none)"
        )
    return [k for k, _ in found], [i for _, i in found], named_unit


def infer_time_unit(times: np.ndarray) -> str | None:
    """The unit that gives `times` (increasing numbers) a plausible step rate nearest TYPICAL_RATE_HZ, or None."""
    step = float(np.median(np.diff(times)))
    rates = {unit: NS_PER_S / (step * ns) for unit, ns in NS_PER_UNIT.items()}
    plausible = {u: r for u, r in rates.items() if PLAUSIBLE_RATE_HZ[0] <= r <= PLAUSIBLE_RATE_HZ[1]}
    return min(plausible, key=lambda u: abs(np.log(plausible[u] / TYPICAL_RATE_HZ)), default=None)


def _time_unit(times: np.ndarray, columns: CsvColumns, named: str | None, header_name: str, p: Path) -> tuple[str, str]:
    """(unit, how it was found) of the time column; refuses a stated unit that gives an implausible rate."""
    step = float(np.median(np.diff(times)))
    guess = infer_time_unit(times)
    stated = columns.time_unit or named
    if stated is None:
        if guess is None:
            raise RecordingError(
                f"{p}: the time column {header_name!r} (median step {step:g}) gives no plausible step rate in "
                f"any unit; state its unit with --column time_unit=s|ms|us|ns"
            )
        rate = NS_PER_S / (step * NS_PER_UNIT[guess])
        how = f"inferred: median step {step:g} {guess} = {rate:.4g} Hz"
        log.info("%s: time unit %s (%s); state it with --column time_unit=UNIT", p, guess, how)
        return guess, how
    rate = NS_PER_S / (step * NS_PER_UNIT[stated])
    if not PLAUSIBLE_RATE_HZ[0] <= rate <= PLAUSIBLE_RATE_HZ[1]:
        hint = f" (in {guess} it would be {NS_PER_S / (step * NS_PER_UNIT[guess]):.4g} Hz)" if guess else ""
        where = "--column time_unit" if columns.time_unit else f"the header {header_name!r}"
        raise RecordingError(
            f"{p}: with the time in {stated} ({where}) the median step is {step:g} {stated}, a rate of {rate:.4g} Hz, "
            f"outside the {PLAUSIBLE_RATE_HZ[0]:g}-{PLAUSIBLE_RATE_HZ[1]:g} Hz of a robot recording{hint}; "
            f"state the right unit with --column time_unit=UNIT"
        )
    return stated, "stated with --column time_unit" if columns.time_unit else f"named in the header {header_name!r}"


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
    keys, index, named_unit = _find_columns(header, columns, p)
    wanted = [rows[0][i].strip().strip("_").strip() for i in index]  # the header names, padding stripped
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
    back = np.diff(values[:, 0]) <= 0
    if back.any():
        r = int(np.flatnonzero(back)[0]) + 1
        raise RecordingError(
            f"{p}: time goes backwards (or repeats) at line {lines[r + 1]} ({values[r - 1, 0]} then {values[r, 0]})"
        )
    if values[0, 0] < 0:
        raise RecordingError(f"{p}: negative time {values[0, 0]} on line {lines[1]}")
    unit, how = _time_unit(values[:, 0], columns, named_unit, wanted[0], p)
    ts = np.round(values[:, 0] * NS_PER_UNIT[unit]).astype(np.int64)  # (N,)
    if (np.diff(ts) <= 0).any():
        r = int(np.flatnonzero(np.diff(ts) <= 0)[0]) + 1
        raise RecordingError(f"{p}: line {lines[r + 1]}: the time repeats once in whole nanoseconds of {unit}")
    quat, note = unit_quaternions(values[:, 4:8], f"{p}", [f"line {n}" for n in lines[1:]])
    pose = np.concatenate([values[:, 1:4], quat], axis=1)  # (N, 7)
    gripper = values[:, 8] if "gripper" in keys else np.zeros(len(ts))
    notes = {"time_unit": f"{unit} ({how})", **({"quaternions": note} if note else {})}
    return MotionTable(path=p, timestamps_ns=ts, pose=pose, gripper=gripper, notes=notes)
