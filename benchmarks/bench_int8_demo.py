"""int8 features' effect on the demo: purity, held-out error and free-choice outcomes with int8 against fp32.

Run on demand (each demo takes minutes; one at a time):
    python -m benchmarks.bench_int8_demo --out DIR [--seeds 0 1 2]

Runs `cnep demo --seed S --precision P` into DIR/demo-P-sS for each seed and precision (a folder
that already holds a finished demo's summary.json is reused, not run again), then prints per seed
the CNEP's purity per behaviour and distinct majority experts, the held-out errors of the CNEP and
the CNMP, the free-choice outcomes, and the int8 features' error against the fp32 ones on every
trajectory file (same seed: same recordings, same calibrated weights; only the precision differs).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pipeline.demo.stage import SUMMARY_FILE, DemoConfig, run_demo
from recordings import read_trajectory

PRECISIONS = ("fp32", "int8")


def demo_folder(out: Path, precision: str, seed: int) -> Path:
    """The demo of `precision` and `seed` under `out`, run now unless a finished one is there."""
    folder = out / f"demo-{precision}-s{seed}"
    if not (folder / SUMMARY_FILE).is_file():
        run_demo(DemoConfig(out=folder, seed=seed, precision=precision, quiet=True, force=folder.exists()))
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
    return {"steps": len(cos), "cosine_min": float(cos.min()), "cosine_median": float(np.median(cos)),
            "relative_l2_median": float(np.median(rel)), "relative_l2_max": float(rel.max())}


def describe(summary: dict) -> str:
    """One block of lines: purity, held-out errors, free choice, extraction time."""
    behaviours = summary["behaviours"]
    purity = " ".join(f"{name} {row['purity']:.2f}->{row['expert']}" for name, row in behaviours.items())
    lines = [f"  purity: {purity}; {len({row['expert'] for row in behaviours.values()})} distinct experts"]
    for model, row in summary["heldout"].items():
        lines.append(f"  {model}: held-out position RMSE {100 * row['position_rmse_m']:.2f} cm (median "
                     f"{100 * row['position_rmse_median_m']:.2f}), gripper MAE {1000 * row['gripper_mae_m']:.2f} mm, "
                     f"behaviour accuracy {row['behaviour_accuracy']:.2f}; free choice in a slot "
                     f"{summary['free_choice'][model]['valid']:.2f}")
    lines.append(f"  extract stage {summary['seconds']['extract']:.1f} s")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the demos (kept, reused)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = parser.parse_args()
    for seed in args.seeds:
        folders = {precision: demo_folder(args.out, precision, seed) for precision in PRECISIONS}
        for precision, folder in folders.items():
            print(f"seed {seed}, {precision}:")
            print(describe(json.loads((folder / SUMMARY_FILE).read_text())))
        error = feature_error(folders["fp32"], folders["int8"])
        print(f"seed {seed}: int8 vs fp32 features over {error['steps']} steps: cosine min {error['cosine_min']:.5f} "
              f"median {error['cosine_median']:.5f}, relative L2 median {error['relative_l2_median']:.4f} "
              f"max {error['relative_l2_max']:.4f}")


if __name__ == "__main__":
    main()
