"""PNG figures of `cnep evaluate` (like the paper's figure of generated trajectories), with matplotlib (`plots` extra).

One figure per (table, set): the training demonstrations coloured by mode with every paper query's
conditioning points (x: intermediate point, +: end point), then one panel per example query with the
demonstrations in grey, the ground truth dashed and each method's generated trajectory.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from cnep.outputs import write_output
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.jobs import queries


def _pyplot():
    try:
        import matplotlib
    except ImportError as exc:
        raise PipelineError("figures need matplotlib: `pip install .[plots]`, or run with --no-figures") from exc
    matplotlib.use("Agg")  # files only, never a window
    import matplotlib.pyplot as plt

    return plt


def _demos(ax, t: np.ndarray, demos: np.ndarray, colours, width: float, alpha: float) -> None:
    """All demonstrations (N, T, dy), first output column, as one collection (one artist, fast to draw)."""
    from matplotlib.collections import LineCollection

    segments = np.stack([np.broadcast_to(t, demos.shape[:2]), demos[..., 0]], axis=-1)  # (N, T, 2)
    ax.add_collection(LineCollection(segments, colors=colours, linewidths=width, alpha=alpha))
    ax.autoscale_view()


def plot_set(
    path: Path, set_name: str, n_queries: int, generated: dict[str, np.ndarray], title: str, protocol: str = "paper"
) -> None:
    """Write the figure of one set (seed 0) to `path`; `generated`: row label -> (k, T, dy) on the first k
    queries of `protocol` ("paper", or "commitment": one shared point, no ground truth)."""
    plt = _pyplot()
    s, qs = queries(set_name, 0, n_queries)
    k = min(len(v) for v in generated.values())
    t = np.arange(s.steps) / (s.steps - 1)
    fig, axes = plt.subplots(1, k + 1, figsize=(4 * (k + 1), 3.4), sharey=True, squeeze=False)
    axes = axes[0]
    colours = plt.get_cmap("tab10")
    _demos(axes[0], t, s.train, [colours(m % 10) for m in s.train_modes], width=0.6, alpha=0.5)
    for q in qs[protocol]:
        if protocol == "commitment":
            axes[0].plot(q.obs_t, q.obs_y[:, 0], "o", color="red", ms=4)
            continue
        axes[0].plot(q.obs_t[:-1], q.obs_y[:-1, 0], "x", color="red", ms=5)
        axes[0].plot(q.obs_t[-1:], q.obs_y[-1:, 0], "+", color="blue", ms=7)
    axes[0].set_title("demonstrations and conditioning points", fontsize=9)
    for i, ax in enumerate(axes[1:]):
        q = qs[protocol][i]
        _demos(ax, t, s.train, "0.85", width=0.5, alpha=1.0)
        if protocol == "paper":
            ax.plot(t, q.truth[:, 0], "k--", lw=1.5, label="truth")
        for j, (label, out) in enumerate(generated.items()):
            ax.plot(t, out[i, :, 0], color=colours(j % 10), lw=1.2, label=label)
        ax.plot(q.obs_t, q.obs_y[:, 0], "o", color="black", ms=5)
        ax.set_title(f"query {i + 1}", fontsize=9)
    axes[-1].legend(fontsize=7, loc="best")
    for ax in axes:
        ax.set_xlabel("t")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_output(path, buffer.getvalue())
