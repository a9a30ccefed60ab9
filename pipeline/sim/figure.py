"""A picture of one closed-loop episode: a strip of camera frames, and the scene from above as the task's drawing
describes it (sim.drawing: its shapes, those that change as they ended, its object where it started and ended) with
the executed path and the waypoints the policy predicted at a few steps (in the active expert's colour).
matplotlib comes from the `plots` extra; it is imported when the figure is drawn.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from cnep.outputs import write_output
from cnep.pipeline.replay.viewer import PALETTE, PATH_COLOR
from cnep.sim import scene as S
from cnep.sim.drawing import Drawing, Shape
from cnep.sim.episode import EpisodeResult

FIGURE_FILE = "episode.png"
FRAMES = 6  # camera frames in the strip, evenly spaced over the episode
PREDICTIONS = 4  # reads whose predicted waypoints are drawn, evenly spaced


def draw_episode(ep: EpisodeResult, title: str, path: Path, drawing: Drawing) -> Path:
    """Draw episode `ep` (run with its frames recorded), its scene as `drawing` says, into the PNG `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(ep.states)
    fig = plt.figure(figsize=(12, 5.2), dpi=100)
    grid = fig.add_gridspec(2, FRAMES + 3, height_ratios=(1, 2.2))
    for i, k in enumerate(np.linspace(0, n - 1, FRAMES).round().astype(int)):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(ep.frames[k])
        ax.set_title(f"step {k} ({k * S.CONTROL_PERIOD_S:.1f} s)", fontsize=8)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :FRAMES])
    ended = {shape.name: shape for step in sorted(drawing.changes) for shape in drawing.changes[step]}
    for shape in (*drawing.shapes, *ended.values()):
        _from_above(ax, shape, alpha=0.35 if shape.name == S.TABLE_GEOM else 0.8)
    for k, alpha in ((0, 0.35), (n - 1, 0.9)):
        _object_from_above(ax, drawing.obj, ep.object_poses[k], alpha)
    for k in np.unique(np.linspace(0, len(ep.predicted) - 1, PREDICTIONS).round().astype(int)):
        color = np.asarray(PALETTE[int(ep.experts[k]) % len(PALETTE)]) / 255
        ax.plot(*ep.predicted[k][:, :2].T, ":", color=color, lw=1.5, label=f"predicted at step {k}")
    ax.plot(*ep.states[:, :2].T, "-", color=np.asarray(PATH_COLOR) / 400, lw=2, label="executed path")
    ax.set_aspect("equal")
    ax.set_xlim(*drawing.view[0])
    ax.set_ylim(*drawing.view[1])
    ax.set_xlabel("x (m): left < 0 < right, facing +y")
    ax.set_ylabel("y (m)")
    ax.set_title("from above", fontsize=9)
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    fig.suptitle(f"{title}: {drawing.outcome}, {ep.switches} expert switches", fontsize=10)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(fig)
    return write_output(path, buffer.getvalue())


def _from_above(ax, shape: Shape, alpha: float) -> None:
    """`shape`'s boxes (or discs) seen from above, labelled with its name (not the table's)."""
    from matplotlib.patches import Circle, Rectangle

    label = None if shape.name == S.TABLE_GEOM else shape.name
    for (x, y, _), (hx, hy, _) in zip(shape.centres, shape.half_sizes):
        patch = Circle((x, y), hx) if shape.disc else Rectangle((x - hx, y - hy), 2 * hx, 2 * hy)
        patch.set(color=shape.rgba[:3], alpha=alpha, label=label)
        ax.add_patch(patch)
        label = None  # one legend entry per shape


def _object_from_above(ax, obj: Shape, pose: np.ndarray, alpha: float) -> None:
    """The object's box seen from above at `pose` (7,): position and quaternion xyzw (turned by its yaw)."""
    from matplotlib.patches import Rectangle

    (hx, hy, _), (x, y) = obj.half_sizes[0], pose[:2]
    qx, qy, qz, qw = pose[3:7]
    yaw = math.degrees(math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)))
    box = Rectangle((x - hx, y - hy), 2 * hx, 2 * hy, angle=yaw, rotation_point="center")
    box.set(color=obj.rgba[:3], alpha=alpha)
    ax.add_patch(box)
