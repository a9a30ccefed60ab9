"""int8 features' effect on the demo: purity, held-out error and free-choice outcomes with int8 against fp32.

Run on demand (each demo takes minutes; one at a time):
    python -m benchmarks.bench_int8_demo --out DIR [--seeds 0 1 2] [--control]

Runs `cnep demo --seed S --precision P` into DIR/demo-P-sS for each seed and precision (a folder
that already holds a finished demo's summary.json is reused, not run again), then prints per seed
the CNEP's purity per behaviour and distinct majority experts, the held-out errors of the CNEP and
the CNMP, the free-choice outcomes, and the int8 features' error against the fp32 ones on every
trajectory file (same seed: same recordings, same calibrated weights; only the precision differs),
set against the signal the models read: how far apart the first-step features (what the held-out
evaluation conditions on) of two training scenes lie, for the same and for different behaviours.

--control adds, per seed, the fp32 demo with its features extracted by OpenVINO instead of ONNX
Runtime (DIR/demo-fp32-openvino-sS): the same graph, features within ~3e-7 relative error, so any
difference it makes to the results measures how far training moves under a negligible change of
its inputs, the yardstick for int8's ~2 % change.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from unittest import mock

import numpy as np

from cnep.pipeline.demo import stage
from cnep.pipeline.demo.config import DemoConfig
from cnep.pipeline.demo.generator import LABEL_KEY
from cnep.pipeline.demo.scene import BEHAVIOURS
from cnep.pipeline.demo.stage import SUMMARY_FILE, run_demo
from cnep.recordings import read_demonstration, read_trajectory

PRECISIONS = ("fp32", "int8")


def demo_folder(out: Path, precision: str, seed: int, backend: str = "auto") -> Path:
    """The demo of `precision` and `seed` under `out` (features on `backend`), run now unless a finished one is
    there."""
    folder = out / (f"demo-{precision}-s{seed}" if backend == "auto" else f"demo-{precision}-{backend}-s{seed}")
    if not (folder / SUMMARY_FILE).is_file():
        config = DemoConfig(out=folder, seed=seed, precision=precision, quiet=True, force=folder.exists())
        made = stage.ExtractConfig

        def with_backend(**options) -> stage.ExtractConfig:  # the demo has no backend option: set it here
            return dataclasses.replace(made(**options), backend=backend)

        with mock.patch.object(stage, "ExtractConfig", with_backend):
            run_demo(config)
    return folder


def feature_error(fp32: Path, int8: Path) -> dict[str, float]:
    """int8 against fp32 features over every step of every trajectory file of the two demos: cosine, relative L2."""
    cosines, relative = [], []
    for path in sorted((fp32 / "trajectories").rglob("*.mcap")):
        a = read_trajectory(path).features  # (T, 1280)
        b = read_trajectory(int8 / path.relative_to(fp32)).features  # (T, 1280)
        cosines.append((a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1))
        relative.append(np.linalg.norm(a - b, axis=1) / np.linalg.norm(a, axis=1))
    cos, rel = np.concatenate(cosines), np.concatenate(relative)
    return {
        "steps": len(cos),
        "cosine_min": float(cos.min()),
        "cosine_median": float(np.median(cos)),
        "relative_l2_median": float(np.median(rel)),
        "relative_l2_max": float(rel.max()),
    }


def first_step_spread(demo: Path) -> dict[str, float]:
    """Relative L2 distances between the first-step features of the demo's scene-decided training files
    (divided by the median feature norm): medians over pairs of the same and of different behaviours."""
    features, labels = [], []
    for path in sorted((demo / "trajectories" / "train").glob("*.mcap")):
        label = read_demonstration(demo / "recorded" / "train" / path.name).episode.extra[LABEL_KEY]
        if label in BEHAVIOURS:  # free-choice scenes have no behaviour of their own
            features.append(read_trajectory(path).features[0])  # (1280,)
            labels.append(label)
    x, y = np.stack(features), np.asarray(labels)  # (n, 1280), (n,)
    distance = np.linalg.norm(x[:, None] - x[None], axis=-1) / np.median(np.linalg.norm(x, axis=1))  # (n, n)
    same = (y[:, None] == y[None]) & ~np.eye(len(y), dtype=bool)
    different = y[:, None] != y[None]
    return {
        "same": float(np.median(distance[same])),
        "different": float(np.median(distance[different])),
        "different_min": float(distance[different].min()),
    }


def describe(summary: dict) -> str:
    """One block of lines: purity, held-out errors, free choice, the scene change, extraction time."""
    behaviours = summary["behaviours"]
    purity = " ".join(f"{name} {row['purity']:.2f}->{row['expert']}" for name, row in behaviours.items())
    lines = [f"  purity: {purity}; {len({row['expert'] for row in behaviours.values()})} distinct experts"]
    for model, row in summary["heldout"].items():
        lines.append(
            f"  {model}: held-out position RMSE {100 * row['position_rmse_m']:.2f} cm (median "
            f"{100 * row['position_rmse_median_m']:.2f}), gripper MAE {1000 * row['gripper_mae_m']:.2f} mm, "
            f"{row['wrong_behaviour']} of {row['n']} read as the wrong behaviour; free choice in a slot "
            f"{summary['free_choice'][model]['valid']:.2f}"
        )
    for change in summary["scene_change"]:
        lines.append(
            f"  scene change at step {change['change_step']}: expert {change['expert_before']} -> "
            f"{change['expert_after']}, switches {change['switches']}"
        )
    lines.append(f"  extract stage {summary['seconds']['extract']:.1f} s")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the demos (kept, reused)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--control", action="store_true", help="also the fp32 demo with OpenVINO features")
    args = parser.parse_args()
    for seed in args.seeds:
        folders = {precision: demo_folder(args.out, precision, seed) for precision in PRECISIONS}
        if args.control:
            folders["fp32 on OpenVINO (control)"] = demo_folder(args.out, "fp32", seed, backend="openvino")
        for precision, folder in folders.items():
            print(f"seed {seed}, {precision}:")
            print(describe(json.loads((folder / SUMMARY_FILE).read_text())))
        for name, folder in folders.items():
            if name == "fp32":
                continue
            error = feature_error(folders["fp32"], folder)
            print(
                f"seed {seed}: {name} vs fp32 features over {error['steps']} steps: cosine min "
                f"{error['cosine_min']:.6f} median {error['cosine_median']:.6f}, relative L2 median "
                f"{error['relative_l2_median']:.2e} max {error['relative_l2_max']:.2e}"
            )
        spread = first_step_spread(folders["fp32"])
        print(
            f"seed {seed}: fp32 first-step features of two training scenes lie {spread['same']:.4f} apart (relative "
            f"L2, median) for the same behaviour, {spread['different']:.4f} for different ones (closest pair "
            f"{spread['different_min']:.4f})"
        )


if __name__ == "__main__":
    main()
