"""Do the features carry the pick-and-place scene's cues? Probes on the first frames of fresh scenes.

    python examples/pick_place_probe.py OUT [--scenes N] [--json FILE]

OUT is a folder made by `cnep sim pick-place --out OUT`. N fresh scenes (drawn decided or free, as the
demonstrations are, from seeds no demonstration or episode uses, on the run's version of the environment: its
summary's `env_version`) are rendered at their first step and turned into features by the exported CNEP's own
feature graph (OUT/policies/cnep-seed0: what the policy sees in the loop). On the features, standardised with the
fitting rows' mean and std, a ridge probe onto one-hot targets (lambda RIDGE, as examples/first_read.py) and the
nearest neighbour are fitted on the first two thirds of the scenes and scored on the rest, for each label:

    orientation   how the bar lies (along x or y: the grasp), chance 1/2
    taken <place> whether a cup stands on that mat, chance 1/2 (about: the draw)
    valid         the places the scene allows (one of the grasp's two, or both: six classes), chance about 1/4

Prints one markdown row per label; --json FILE writes them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import cnep.sim
from cnep.runtime.exported import load_features
from cnep.runtime.frames import pixel_buffer, resize_frame
from cnep.sim import PickPlaceEnv
from cnep.sim.tasks.pick_place import scene as P

RIDGE = 1.0
PROBE_SEED = 5_000_000  # above the demonstrations' seeds (pipeline.sim.generate.DEMO_SEED_OFFSET + ...)


def scenes(features, n: int, version: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The first frames' features (n, 1280) of n fresh scenes of the environment's `version` and their labels
    (name -> (n,) strings)."""
    env = PickPlaceEnv(version=version)
    pixels = pixel_buffer(1)
    rows, labels = [], {"orientation": [], "valid": [], **{f"taken {name}": [] for name, _, _ in P.PLACES}}
    try:
        for i in range(n):
            observation, info = env.reset(seed=PROBE_SEED + i)
            resize_frame(observation[env.image_key], pixels[0])
            rows.append(features(pixels)[0])
            labels["orientation"].append(info["orientation"])
            labels["valid"].append("+".join(P.PLACES[j][0] for j in info["valid"]))
            for (name, _, _), taken in zip(P.PLACES, info["taken"]):
                labels[f"taken {name}"].append(str(taken))
    finally:
        env.close()
    return np.asarray(rows, np.float64), {k: np.asarray(v) for k, v in labels.items()}


def probe(x: np.ndarray, y: np.ndarray, fit: int) -> dict:
    """Ridge and 1-NN accuracy on rows [fit:] after fitting on rows [:fit]; the majority class's share there."""
    mean, std = x[:fit].mean(0), x[:fit].std(0) + 1e-6
    z = (x - mean) / std
    classes = np.unique(y[:fit])
    targets = (y[:fit, None] == classes).astype(np.float64)  # (fit, c)
    gram = z[:fit] @ z[:fit].T + RIDGE * np.eye(fit)
    ridge = classes[(z[fit:] @ z[:fit].T @ np.linalg.solve(gram, targets)).argmax(1)]
    nearest = y[:fit][((z[fit:, None] - z[None, :fit]) ** 2).sum(-1).argmin(1)]
    values, counts = np.unique(y[:fit], return_counts=True)
    majority = values[counts.argmax()]
    return {
        "ridge": round(float(np.mean(ridge == y[fit:])), 3),
        "nearest": round(float(np.mean(nearest == y[fit:])), 3),
        "majority": round(float(np.mean(y[fit:] == majority)), 3),
        "classes": len(classes),
    }


def main(argv: list[str] | None = None) -> dict[str, dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="a folder made by `cnep sim pick-place --out`")
    parser.add_argument("--scenes", type=int, default=150, help="fresh scenes (default 150)")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args(argv)
    cnep.sim.require_extra()
    features = load_features(args.out / "policies" / "cnep-seed0", threads=1)
    version = json.loads((args.out / "summary.json").read_text()).get("env_version", 0)  # none: the first version's
    x, labels = scenes(features, args.scenes, version)
    fit = 2 * args.scenes // 3
    rows = {name: probe(x, y, fit) for name, y in labels.items()}
    print(f"{args.scenes - fit} held-out scenes (fitted on {fit})\n")
    print("| label | classes | ridge | 1-NN | majority |\n|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['classes']} | {r['ridge']:.2f} | {r['nearest']:.2f} | {r['majority']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
