"""Validation of everything that goes into or comes out of a recording file, in one place.

Each function takes the value, the expected sizes and `where` (the file or record being checked,
used as the message prefix), converts to the canonical dtype and shape, and raises `RecordingError`
stating the rule, the offending value and the fix.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import numpy as np

from cnep.recordings.constants import (
    BLOCK_FEATURES,
    BLOCKS_BY_WIDTH,
    MAX_FRAME_PIXELS,
    POSE_DIM,
    SUPPORTED_FORMAT_VERSIONS,
)
from cnep.recordings.errors import RecordingError

JPEG_MAGIC = b"\xff\xd8"
# JPEG start-of-frame markers (they hold the image size); C4, C8 and CC share the range but are not frames.
SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# A quaternion whose length differs from the recording's typical length by more than this share is not a rotation
# of the same kind: normalising it would turn it into an unrelated orientation (a 0.55 among unit ones: ~130 degrees).
QUATERNION_TOLERANCE = 0.1
# A pose or gripper value further from the recording's median than this many times its spread (`_spread`) is a
# corrupt value, not motion: it would set the normaliser's scale and flatten every other demonstration.
OUTLIER_SPREADS = 1000.0

log = logging.getLogger(__name__)


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def check_timestamps(timestamps_ns: object, where: str) -> np.ndarray:
    """Return timestamps as int64 (T,) with T >= 1, all >= 0 and strictly increasing (ns)."""
    ts = np.asarray(timestamps_ns)
    if ts.ndim != 1 or ts.shape[0] == 0:
        raise RecordingError(f"{where}: timestamps_ns must have shape (T,) with T >= 1, got shape {ts.shape}")
    if not np.issubdtype(ts.dtype, np.integer):
        raise RecordingError(f"{where}: timestamps_ns must be integer nanoseconds, got dtype {ts.dtype}")
    ts = ts.astype(np.int64, copy=False)
    if (ts < 0).any():
        i = _first_bad(ts < 0)
        raise RecordingError(f"{where}: timestamp {ts[i]} ns at step {i} is negative; MCAP log times are unsigned")
    back = np.diff(ts) <= 0
    if back.any():
        i = _first_bad(back)
        raise RecordingError(
            f"{where}: timestamps go backwards (or repeat) at step {i + 1}: "
            f"{ts[i]} ns then {ts[i + 1]} ns; each step needs a strictly later time"
        )
    return ts


def check_finite(values: np.ndarray, name: str, where: str) -> None:
    """Raise if `values` holds NaN or infinity, naming the first bad (step, column)."""
    bad = ~np.isfinite(values)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise RecordingError(
            f"{where}: {name} holds a non-finite value ({values[tuple(idx)]}) at index {tuple(int(i) for i in idx)}; "
            "drop or repair that step before writing"
        )


def check_pose(pose: object, n_steps: int, where: str) -> np.ndarray:
    """Return pose as float64 (T, 7): xyz in m, then a non-zero quaternion xyzw."""
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (n_steps, POSE_DIM):
        raise RecordingError(
            f"{where}: pose must have shape ({n_steps}, {POSE_DIM}) (xyz + quaternion xyzw), got {arr.shape}"
        )
    check_finite(arr, "pose", where)
    norms = np.linalg.norm(arr[:, 3:], axis=1)
    if (norms < 1e-6).any():
        i = _first_bad(norms < 1e-6)
        raise RecordingError(f"{where}: pose quaternion at step {i} has zero length; use (0, 0, 0, 1) for no rotation")
    return arr


def check_gripper(gripper: object, n_steps: int, where: str) -> np.ndarray:
    """Return gripper state as float64 (T,), in the recording's own units."""
    arr = np.asarray(gripper, dtype=np.float64)
    if arr.shape != (n_steps,):
        raise RecordingError(f"{where}: gripper must have shape ({n_steps},), got {arr.shape}")
    check_finite(arr, "gripper", where)
    return arr


def check_frames(frames: Sequence[bytes] | None, n_steps: int, where: str) -> list[bytes] | None:
    """Return frames as a list of T JPEG byte strings, or None for a motion-only recording."""
    if frames is None:
        return None
    out = list(frames)
    if len(out) != n_steps:
        raise RecordingError(f"{where}: {len(out)} frames for {n_steps} steps; give one JPEG frame per step or none")
    for i, frame in enumerate(out):
        if not isinstance(frame, (bytes, bytearray)) or not bytes(frame[:2]) == JPEG_MAGIC:
            raise RecordingError(f"{where}: frame {i} is not JPEG data (it must start with bytes FF D8)")
        size = jpeg_size(frame)
        if size is None or size[0] * size[1] > MAX_FRAME_PIXELS:
            said = (
                "its header declares no frame size"
                if size is None
                else f"it declares {size[0]}x{size[1]} pixels, more than the {MAX_FRAME_PIXELS} a frame may have"
            )
            raise RecordingError(
                f"{where}: frame {i} is not a decodable JPEG ({said}); a frame is a JPEG image of at most "
                f"{MAX_FRAME_PIXELS} pixels: ingest the recording again from its source"
            )
    return [bytes(f) for f in out]


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's start-of-frame marker, without decoding it; None if there is none."""
    i = 2
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if 0xD0 <= marker <= 0xD9 or marker == 0x01:  # markers without a length
            i += 2
            continue
        if marker in SOF_MARKERS and i + 9 <= len(data):
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + int.from_bytes(data[i + 2 : i + 4], "big")
    return None


def check_blocks(blocks: Mapping[str, Sequence[int]] | None, width: int, where: str) -> dict[str, tuple[int, int]]:
    """Return the column blocks of a matrix of `width` columns; only those in `BLOCKS_BY_WIDTH` exist."""
    if width not in BLOCKS_BY_WIDTH:
        raise RecordingError(
            f"{where}: vector width {width} is not a known layout; expected one of {sorted(BLOCKS_BY_WIDTH)} "
            "(1288 = features|pose|gripper, 8 = pose|gripper for motion-only recordings)"
        )
    expected = {k: tuple(v) for k, v in BLOCKS_BY_WIDTH[width].items()}
    if blocks is None:
        return expected
    try:
        given = {str(k): (int(v[0]), int(v[1])) for k, v in blocks.items()}
    except (TypeError, ValueError, IndexError, AttributeError) as exc:
        raise RecordingError(f"{where}: column layout is not a {{block: [start, stop]}} mapping ({exc})") from None
    if given != expected:
        raise RecordingError(f"{where}: column layout {given} does not match the width-{width} layout {expected}")
    return expected


def check_matrix(data: object, n_steps: int, where: str) -> np.ndarray:
    """Return the per-step vectors as C-contiguous float32 (T, D) with finite values."""
    with np.errstate(over="ignore"):  # a value beyond float32 becomes inf, reported by check_finite
        arr = np.ascontiguousarray(np.asarray(data, dtype=np.float32))
    if arr.ndim != 2 or arr.shape[0] != n_steps:
        raise RecordingError(f"{where}: data must have shape ({n_steps}, D), got {arr.shape}")
    check_finite(arr, "data (float32)", where)
    return arr


def check_views(views: object, n_steps: int, blocks: Mapping[str, tuple[int, int]], where: str) -> np.ndarray | None:
    """Return a trajectory's feature views as C-contiguous float32 (V, T, F) with finite values, F the feature
    block's width, or None for none (perception.views)."""
    if views is None:
        return None
    if BLOCK_FEATURES not in blocks:
        raise RecordingError(f"{where}: feature views need a feature block; this trajectory is motion-only")
    a, b = blocks[BLOCK_FEATURES]
    with np.errstate(over="ignore"):
        arr = np.ascontiguousarray(np.asarray(views, dtype=np.float32))
    if arr.ndim != 3 or arr.shape[0] < 1 or arr.shape[1:] != (n_steps, b - a):
        raise RecordingError(f"{where}: feature views must have shape (V >= 1, {n_steps}, {b - a}), got {arr.shape}")
    check_finite(arr, "feature views (float32)", where)
    return arr


def check_extractor(extractor: Mapping[str, str] | None, blocks: Mapping[str, object], where: str) -> dict[str, str]:
    """Return the extractor identity: required (non-empty) with a feature block, empty without one."""
    ident = {} if extractor is None else dict(extractor)
    for k, v in ident.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise RecordingError(f"{where}: extractor identity must map str to str, got {k!r}: {v!r}")
    if BLOCK_FEATURES in blocks and not ident:
        raise RecordingError(
            f"{where}: a trajectory with a feature block needs the feature extractor's identity "
            "(e.g. architecture, weights name, weights hash)"
        )
    if BLOCK_FEATURES not in blocks and ident:
        raise RecordingError(f"{where}: extractor identity given but the layout has no feature block")
    return ident


def check_format_version(version: str | None, where: str) -> str:
    """Return `version` if this library reads it; otherwise say what to do."""
    if version not in SUPPORTED_FORMAT_VERSIONS:
        raise RecordingError(
            f"{where}: unknown format_version {version!r}; this cnep-pipeline reads "
            f"{sorted(SUPPORTED_FORMAT_VERSIONS)}. Upgrade cnep-pipeline or re-create the file with this version"
        )
    return version


def check_fps(fps: object, where: str) -> float:
    """Return the nominal step rate in Hz, a finite number > 0."""
    try:
        value = float(fps)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise RecordingError(f"{where}: fps must be a number in Hz, got {fps!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise RecordingError(f"{where}: fps must be finite and > 0 Hz, got {value}")
    return value


def unit_quaternions(
    quat: np.ndarray, where: str, labels: Sequence[str] | None = None
) -> tuple[np.ndarray, str | None]:
    """Unit quaternions (N, 4) from recorded ones (N, 4); returns them and a note for the metadata, or None.

    A zero quaternion, or one whose length is far from the others' (QUATERNION_TOLERANCE), is refused naming
    its row (`labels[i]`, default `step i`); quaternions that all share one length other than 1 are
    normalised, with a warning and the note saying so.
    """
    label = (lambda i: labels[i]) if labels is not None else (lambda i: f"step {i}")
    norms = np.linalg.norm(quat, axis=1)  # (N,)
    if (norms < 1e-6).any():
        i = _first_bad(norms < 1e-6)
        raise RecordingError(f"{where}: {label(i)}: the quaternion has zero length; use (0, 0, 0, 1) for no rotation")
    typical = float(np.median(norms))
    off = np.abs(norms / typical - 1) > QUATERNION_TOLERANCE
    if off.any():
        i = _first_bad(off)
        raise RecordingError(
            f"{where}: {label(i)}: the quaternion has length {norms[i]:.3g} where the others have about {typical:.3g}, "
            f"so it is no rotation of the recording ({int(off.sum())} such); fix or drop that row"
        )
    if abs(typical - 1) <= QUATERNION_TOLERANCE:
        return quat / norms[:, None], None
    note = f"normalised from lengths {norms.min():.3g}-{norms.max():.3g}"
    log.warning(
        "%s: the quaternions have length about %.3g, not 1; %s (assumed: scaled rotations)", where, typical, note
    )
    return quat / norms[:, None], note


def _spread(values: np.ndarray, floor: float) -> float:
    """How far the bulk of `values` (T,) spreads: the 10-90 % range, or `floor` if wider, or a tenth of the bulk's
    magnitude if wider still (a constant column has no range)."""
    low, high = np.quantile(values, [0.1, 0.9])
    return max(float(high - low), floor, 0.1 * max(abs(low), abs(high)))


def check_outliers(pose: np.ndarray, gripper: np.ndarray, where: str, labels: Sequence[str] | None = None) -> None:
    """Refuse a pose xyz (m) or gripper value far from the rest of its recording (OUTLIER_SPREADS spreads from the
    median: a corrupt value, not motion), naming the row (`labels[i]`, default `step i`), the column and the value.

    The spread has a floor of 0.1 m for positions and 1 unit for the gripper, so a robot that waits and then moves
    fast, or a gripper that closes once, is never refused.
    """
    label = (lambda i: labels[i]) if labels is not None else (lambda i: f"step {i}")
    columns = [("x", pose[:, 0], 0.1), ("y", pose[:, 1], 0.1), ("z", pose[:, 2], 0.1), ("gripper", gripper, 1.0)]
    for name, values, floor in columns:
        centre, spread = float(np.median(values)), _spread(values, floor)
        far = np.abs(values - centre) > OUTLIER_SPREADS * spread
        if far.any():
            i = _first_bad(far)
            low, high = np.quantile(values, [0.1, 0.9])
            raise RecordingError(
                f"{where}: {label(i)}: {name} is {values[i]:.6g}, far outside the rest of the recording (10-90 % of "
                f"its values lie in {low:.4g}..{high:.4g}); a corrupt value, not motion: fix or drop that row"
            )
