"""The demo's summary figure: for a few replayed held-out scenes, the CNEP's gate over time and, seen from above,
the path each model predicts against the recorded one.

matplotlib comes from the `plots` extra (`make demo` installs it); it is imported when the figure is drawn.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.outputs import write_output
from cnep.pipeline.demo.measures import first_step_prediction, trained_rows
from cnep.pipeline.replay.viewer import PALETTE
from cnep.recordings import read_trajectory

FIGURE_FILE = "summary.png"
DPI = 100
MODEL_STYLES = {"CNEP": {"lw": 2.0}, "CNMP": {"lw": 1.5, "ls": "--", "color": "0.45"}}


@dataclass(frozen=True)
class Scene:
    """One column of the figure: a replayed recording, its online gate (T, d) and a step to mark (or None)."""

    title: str
    recording: Path
    gates: np.ndarray
    marker: int | None = None
    marker_label: str = ""


def first_step_path(checkpoint: Path, recording: Path) -> tuple[np.ndarray, int]:
    """The (T, 3) xyz path (m) the checkpoint's model predicts for `recording` conditioned on its first step, and
    the expert it chose."""
    trained, (rows,) = trained_rows(checkpoint, [recording])
    prediction = first_step_prediction(trained.model, rows)
    return prediction.mean[:, trained.mapping.predicted_xyz(trained.model)], prediction.expert  # (T, 3)


def draw_summary(scenes: list[Scene], checkpoints: dict[str, Path], expert_labels: dict[int, str], png: Path) -> Path:
    """Draw the figure into `png` (written whole or not at all): per scene, the gate probabilities over the steps
    (top; experts named by `expert_labels`, coloured as in Rerun) and the recorded path against each checkpoint's
    prediction from the first step, x and y in cm (bottom)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(scenes), figsize=(4.2 * len(scenes), 7), squeeze=False)
    for column, scene in enumerate(scenes):
        gate_axis, path_axis = axes[0, column], axes[1, column]
        steps = np.arange(len(scene.gates))
        for e in range(scene.gates.shape[1]):
            label = f"expert {e}" + (f" ({expert_labels[e]})" if e in expert_labels else "")
            gate_axis.plot(steps, scene.gates[:, e], color=np.array(PALETTE[e % len(PALETTE)]) / 255, lw=2, label=label)
        if scene.marker is not None:
            gate_axis.axvline(scene.marker, color="0.3", ls=":", lw=1.5)
            gate_axis.text(scene.marker + 0.5, 0.5, scene.marker_label, rotation=90, va="center", fontsize=8)
        gate_axis.set(title=scene.title, ylim=(-0.05, 1.05), xlabel="step")
        if column == 0:
            gate_axis.set_ylabel("gate probability")

        recorded = read_trajectory(scene.recording).pose[:, :3]  # (T, 3) m
        path_axis.plot(100 * recorded[:, 0], 100 * recorded[:, 1], color="k", lw=3, alpha=0.35, label="recorded")
        for name, checkpoint in checkpoints.items():
            xyz, expert = first_step_path(checkpoint, scene.recording)
            style = dict(MODEL_STYLES.get(name, {}))
            style.setdefault("color", np.array(PALETTE[expert % len(PALETTE)]) / 255)
            path_axis.plot(100 * xyz[:, 0], 100 * xyz[:, 1], label=f"{name} from step 0", **style)
        path_axis.plot(100 * recorded[0, 0], 100 * recorded[0, 1], "ko", ms=5)
        path_axis.set(xlabel="x (cm)")
        path_axis.set_aspect("equal", adjustable="datalim")
        path_axis.set_ylabel("y (cm)" if column == 0 else "")
    axes[0, min(1, len(scenes) - 1)].legend(fontsize=8, loc="center right")  # where a decided scene's gate leaves room
    axes[1, 0].legend(fontsize=8)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    write_output(png, buffer.getvalue())
    return png
