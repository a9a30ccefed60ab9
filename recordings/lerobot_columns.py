"""Which entries of a LeRobot dataset's state vector are the end-effector pose and the gripper.

Entries are chosen by the names in `info.json` `features[column].names` or by index. The pose is xyz +
quaternion xyzw (7 entries) or xyz + roll/pitch/yaw in radians (6 entries), converted with
R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes X, Y, Z: the ROS convention). The gripper is the state's entry,
or, where the dataset's `action` names an entry of the same name, the action's: the command (open or
close) a robot was given rather than the opening it measured, which reads the object's width when it
closes on one (`LerobotMapping.gripper_from`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cnep.recordings.errors import RecordingError
from cnep.recordings.lerobot_layout import ACTION
from cnep.recordings.validation import unit_quaternions

NS_PER_S = 1_000_000_000
# Pose names recognised without --pose: xyz + quaternion xyzw, or xyz + roll/pitch/yaw (radians).
DEFAULT_POSE_NAMES = (("x", "y", "z", "qx", "qy", "qz", "qw"), ("x", "y", "z", "roll", "pitch", "yaw"))
GRIPPER_SOURCES = ("action", "state")  # where the gripper is read from (LerobotMapping.gripper_from)


@dataclass(frozen=True)
class LerobotMapping:
    """Which LeRobot features become frames, pose and gripper.

    camera: a `video`/`image` feature key (None: the dataset's only camera, none if it has none; "" for none).
    state: the vector column holding pose and gripper (`observation.state`).
    pose: 7 entries (x y z qx qy qz qw) or 6 (x y z roll pitch yaw, radians, R = Rz(yaw) Ry(pitch)
        Rx(roll)), each a name from `features[state].names` or an index; None: the names above if present.
    gripper: a name or an index (None: the entry named `gripper` if there is one; "" for none, stored as 0.0).
    gripper_from: "action": the entry of the `action` vector that has the gripper entry's name in `features[state]`,
        where the action has one (the commanded open/close, what a policy learns), else the state's; "state": the
        state's entry always (the measured opening).
    """

    camera: str | None = None
    state: str = "observation.state"
    pose: tuple[str, ...] | None = None
    gripper: str | None = None
    gripper_from: str = GRIPPER_SOURCES[0]

    def __post_init__(self) -> None:
        if self.pose is not None and len(self.pose) not in (6, 7):
            raise RecordingError(
                f"LeRobot pose mapping {list(self.pose)}: give 7 entries (x y z qx qy qz qw) "
                f"or 6 (x y z roll pitch yaw)"
            )
        if self.gripper_from not in GRIPPER_SOURCES:
            raise RecordingError(
                f"LeRobot gripper source {self.gripper_from!r}: choose one of {', '.join(GRIPPER_SOURCES)}"
            )


def _vector_names(feature: dict) -> list[str] | None:
    """The per-entry names of a vector feature, or None when `names` does not name each entry."""
    names, shape = feature.get("names"), feature.get("shape") or [0]
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    if isinstance(names, list) and len(names) == shape[0] and all(isinstance(n, str) for n in names):
        return names
    return None


def _index_of(entry: str, names: list[str] | None, width: int, column: str, where: Path) -> int:
    if names is not None and entry in names:
        return names.index(entry)
    if entry.lstrip("-").isdigit():
        index = int(entry)
        if 0 <= index < width:
            return index
        raise RecordingError(
            f"{where}: index {index} is outside {column!r}, a vector of {width} values; "
            f"the pose/gripper mapping needs a longer state vector or other indices"
        )
    raise RecordingError(
        f"{where}: {column!r} has no entry named {entry!r} (names: {names}); map it with "
        f"--pose/--gripper by name or index"
    )


@dataclass(frozen=True)
class StateColumns:
    """Where motion is: the pose's indices (6 or 7) into the vector column `state`, the gripper's index into the
    vector column `gripper_column` (None: no gripper), and a description for the metadata."""

    state: str
    pose: tuple[int, ...]
    gripper_column: str
    gripper: int | None
    described: str


def resolve_columns(info: dict, mapping: LerobotMapping, where: Path) -> StateColumns:
    feature = info["features"].get(mapping.state)
    if feature is None:
        vectors = sorted(k for k, f in info["features"].items() if f.get("dtype") in ("float32", "float64"))
        raise RecordingError(
            f"{where}: no feature {mapping.state!r} (vector features: {vectors}); choose the column with --state-column"
        )
    width = int((feature.get("shape") or [1])[0])
    names = _vector_names(feature)
    pose = mapping.pose
    if pose is None:
        lowered = [n.lower() for n in names] if names else []
        for candidate in DEFAULT_POSE_NAMES:
            if all(c in lowered for c in candidate):
                pose = tuple(names[lowered.index(c)] for c in candidate)
                break
        else:
            raise RecordingError(
                f"{where}: cannot tell which entries of {mapping.state!r} are the end-effector pose "
                f"(names: {names}); give them with --pose x,y,z,qx,qy,qz,qw (or x,y,z,roll,pitch,yaw) "
                f"as names or indices"
            )
    pose_idx = tuple(_index_of(e, names, width, mapping.state, where) for e in pose)
    gripper = mapping.gripper
    if gripper is None:
        gripper = "gripper" if names and "gripper" in names else None
        if gripper is None:
            raise RecordingError(
                f"{where}: no entry named 'gripper' in {mapping.state!r} (names: {names}); give it "
                f'with --gripper NAME|INDEX, or --gripper "" for none'
            )
    grip_idx = _index_of(gripper, names, width, mapping.state, where) if gripper else None
    column, grip_idx, gripper = _gripper_source(info, mapping, names, grip_idx, gripper)
    described = f"{mapping.state}[{','.join(pose)}]" + (f", gripper {column}[{gripper}]" if gripper else "")
    return StateColumns(mapping.state, pose_idx, column, grip_idx, described)


def _gripper_source(
    info: dict, mapping: LerobotMapping, names: list[str] | None, index: int | None, given: str | None
) -> tuple[str, int | None, str | None]:
    """(column, index, entry as described) of the gripper: the action's entry of the same name where
    `mapping.gripper_from` is "action" and the action names one, else the state's entry `index`."""
    name = names[index] if names is not None and index is not None else None
    action = info["features"].get(ACTION)
    action_names = _vector_names(action) if mapping.gripper_from == ACTION and isinstance(action, dict) else None
    if name is None or action_names is None or name not in action_names:
        return mapping.state, index, given
    return ACTION, action_names.index(name), name


def quaternion_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw in radians (N, 3) -> unit quaternions xyzw (N, 4) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    half = rpy / 2.0
    cr, cp, cy = np.cos(half).T
    sr, sp, sy = np.sin(half).T
    return np.stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ],
        axis=1,
    )


def _vectors(table: Any, column: str, where: str) -> np.ndarray:
    """A list-valued (or scalar) Parquet column -> (N, D) float64, without a Python object per value."""
    import pyarrow as pa
    import pyarrow.compute as pc

    values = table.column(column).combine_chunks()
    if values.null_count:
        raise RecordingError(f"{where}: column {column!r} has empty (null) cells")
    n = len(values)
    if pa.types.is_list(values.type) or pa.types.is_large_list(values.type) or pa.types.is_fixed_size_list(values.type):
        lengths = pc.list_value_length(values).to_numpy(zero_copy_only=False)  # (N,)
        if n and (lengths != lengths[0]).any():
            raise RecordingError(
                f"{where}: column {column!r} holds vectors of different lengths ({sorted(set(lengths.tolist()))})"
            )
        flat = values.flatten()
        width = int(lengths[0]) if n else 0
    else:
        flat, width = values, 1
    try:
        return flat.to_numpy(zero_copy_only=False).astype(np.float64).reshape(n, width)
    except (TypeError, ValueError, pa.ArrowException):
        raise RecordingError(f"{where}: column {column!r} does not hold numbers ({values.type})") from None


def _read_vectors(table: Any, column: str, indices: tuple[int, ...], where: str) -> np.ndarray:
    """The vector column `column` (T, D) float64, checked to hold `indices` and finite values."""
    if column not in table.column_names:
        raise RecordingError(f"{where}: no column {column!r} (columns: {table.column_names})")
    vectors = _vectors(table, column, where)  # (T, D)
    if vectors.shape[1] <= max(indices):
        raise RecordingError(
            f"{where}: {column!r} holds {vectors.shape[1]} values per row, the pose/gripper mapping "
            f"reads index {max(indices)}"
        )
    if not np.isfinite(vectors).all():
        raise RecordingError(f"{where}: NaN or infinite values in {column!r}")
    return vectors


def motion_of_rows(table: Any, columns: StateColumns, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(timestamps_ns (T,), pose (T, 7), gripper (T,), notes for the metadata) of an episode's rows, checked."""
    if "timestamp" not in table.column_names:
        raise RecordingError(f"{where}: no column 'timestamp' (columns: {table.column_names})")
    seconds = _vectors(table, "timestamp", where)[:, 0]
    if not np.isfinite(seconds).all():
        raise RecordingError(f"{where}: NaN or infinite values in 'timestamp'")
    same = columns.gripper_column == columns.state
    grip = (columns.gripper,) if columns.gripper is not None else ()
    vectors = _read_vectors(table, columns.state, columns.pose + (grip if same else ()), where)  # (T, D)
    grippers = vectors if same or not grip else _read_vectors(table, columns.gripper_column, grip, where)
    times = np.round(seconds * NS_PER_S).astype(np.int64)  # (T,)
    if times[0] < 0 or (np.diff(times) <= 0).any():
        raise RecordingError(f"{where}: 'timestamp' must start at >= 0 s and increase strictly")
    raw = vectors[:, list(columns.pose)]  # (T, 6 or 7)
    quat = raw[:, 3:] if raw.shape[1] == 7 else quaternion_from_rpy(raw[:, 3:])
    quat, note = unit_quaternions(quat, where, [f"row {i}" for i in range(len(quat))])
    pose = np.concatenate([raw[:, :3], quat], axis=1)  # (T, 7)
    gripper = grippers[:, columns.gripper] if columns.gripper is not None else np.zeros(len(times))
    return times, pose, gripper, {"quaternions": note} if note else {}
