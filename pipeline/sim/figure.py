"""A picture of one closed-loop episode: a strip of camera frames, and the scene from above with the executed path,
the waypoints the policy predicted at a few steps (in the active expert's colour), the box where it started and
ended, and the goal. matplotlib comes from the `plots` extra; it is imported when the figure is drawn.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from cnep.outputs import write_atomically
from cnep.pipeline.replay.viewer import PALETTE, PATH_COLOR
from cnep.sim import scene as S
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.obstacle.scoring import ObstacleEpisode

FIGURE_FILE = "episode.png"
FRAMES = 6  # camera frames in the strip, evenly spaced over the episode
PREDICTIONS = 4  # reads whose predicted waypoints are drawn, evenly spaced


def draw_episode(ep: ObstacleEpisode, title: str, path: Path) -> Path:
    """Draw episode `ep` (run with its frames recorded) into the PNG `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    n = len(ep.states)
    fig = plt.figure(figsize=(12, 5.2), dpi=100)
    grid = fig.add_gridspec(2, FRAMES + 3, height_ratios=(1, 2.2))
    for i, k in enumerate(np.linspace(0, n - 1, FRAMES).round().astype(int)):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(ep.frames[k])
        ax.set_title(f"step {k} ({k * S.CONTROL_PERIOD_S:.1f} s)", fontsize=8)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :FRAMES])
    ax.add_patch(Rectangle((-S.TABLE_HALF[0], -S.TABLE_HALF[1]), 2 * S.TABLE_HALF[0], 2 * S.TABLE_HALF[1],
                           color=S.TABLE_RGBA[:3], alpha=0.35))  # fmt: skip
    ax.add_patch(Circle(O.GOAL_XY, O.GOAL_RADIUS, color=O.GOAL_RGBA[:3], alpha=0.8, label="goal"))
    for k, alpha in ((0, 0.35), (n - 1, 0.9)):
        x, y = ep.object_poses[k, :2]
        ax.add_patch(Rectangle((x - O.BOX_HALF[0], y - O.BOX_HALF[1]), 2 * O.BOX_HALF[0], 2 * O.BOX_HALF[1],
                               color=O.BOX_RGBA[:3], alpha=alpha))  # fmt: skip
    if ep.cue_side is not None:
        cx = O.CUE_XY[0] * (-1 if ep.cue_side == "left" else 1)
        ax.add_patch(Rectangle((cx - O.CUE_HALF, O.CUE_XY[1] - O.CUE_HALF), 2 * O.CUE_HALF, 2 * O.CUE_HALF,
                               color=O.CUE_RGBA[:3], alpha=0.8, label="cue"))  # fmt: skip
    for k in np.unique(np.linspace(0, len(ep.predicted) - 1, PREDICTIONS).round().astype(int)):
        color = np.asarray(PALETTE[int(ep.experts[k]) % len(PALETTE)]) / 255
        ax.plot(*ep.predicted[k][:, :2].T, ":", color=color, lw=1.5, label=f"predicted at step {k}")
    ax.plot(*ep.states[:, :2].T, "-", color=np.asarray(PATH_COLOR) / 400, lw=2, label="executed path")
    ax.set_aspect("equal")
    ax.set_xlim(-S.TABLE_HALF[0], S.TABLE_HALF[0])
    ax.set_ylim(O.START_Y - 0.08, O.GOAL_Y + 0.08)
    ax.set_xlabel("x (m): left < 0 < right, facing the goal")
    ax.set_ylabel("y (m)")
    ax.set_title("from above", fontsize=9)
    ax.legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8)
    outcome = "success" if ep.success else "collision" if ep.collision else "missed the goal"
    fig.suptitle(f"{title}: {outcome}, passed {ep.side}, min clearance {ep.clearance_m * 100:.1f} cm, "
                 f"{ep.switches} expert switches", fontsize=10)  # fmt: skip
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(fig)
    return write_atomically(path, buffer.getvalue())
