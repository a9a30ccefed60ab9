"""Can a task's first frames say where things are? Ridge probes from the frames to the positions its scenes draw.

    python examples/locate_probe.py TASK [--scenes N] [--fit K] [--clean] [--weights W] [--ablation] [--json FILE]

TASK is a `cnep sim` task (obstacle, pick-place, pick-cube, pick-can) on its latest environment. N fresh scenes
(reset seeds from SCENE_SEED, which no demonstration or evaluation episode uses) are rendered at their first step,
and each position the scene draws (the scene's `*_xy` entries: the obstacle's box and goal, a pick task's object) is
the probe's target. The frames become features as `cnep extract --weights W` makes them (seeded random weights
calibrated on the fitting scenes' frames, as on a user's recordings) and, for reference, 32 x 32 pixels. A ridge
probe is fitted on the first K scenes (K: the demonstrations a user records), standardised with their mean and
std, its lambda chosen by 5-fold cross-validation on them, and scored on the rest: the median distance (cm) between
the predicted and the true position, beside predicting the fitting scenes' mean position.

A policy conditioned on those frames cannot place the gripper more precisely than its features locate the
target. --clean turns the robot's sensing off (the camera's and the light's draws, the pixel noise) to show what it
costs. --ablation adds the seeded random weights built without parts of their construction (perception.calibration:
the low-pass kernels, the activation bias), to show what each part keeps. Prints one markdown row per position and
readout; --json FILE writes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import torch
from probes import FOLDS, probe

import cnep.sim
from cnep.perception import FeatureExtractor, resize_frames
from cnep.perception.calibration import ACTIVATION_BIAS, LOW_PASS_CHANNELS, calibrate_random_network, low_pass
from cnep.perception.constants import CALIBRATION_BATCH
from cnep.perception.network import FeatureNet
from cnep.perception.weights import seeded_features
from cnep.pipeline.sim.config import ENV_VERSIONS
from cnep.sim.tasks import TASK_NAMES, find_task

SCENE_SEED = 5_000_000  # above the demonstrations' seeds (sim.task.DEMO_SEED_OFFSET + ...), as the other probes
PIXELS = 32  # the reference readout: the frame resized to PIXELS x PIXELS (area), RGB
SENSING = ("camera_shift_m", "camera_turn_deg", "light_jitter", "pixel_noise")  # what --clean turns off
EVERY_BLOCK = 320  # the widest block's channels: low-pass depthwise kernels in every block
ABLATION = {  # readout -> (the blocks' channels up to which depthwise kernels are low-pass, None: no low_pass; bias)
    "random, torchvision's kernels": (None, ACTIVATION_BIAS),
    "random, low-pass first convolution only": (0, ACTIVATION_BIAS),
    "random, low-pass in every block": (EVERY_BLOCK, ACTIVATION_BIAS),
    "random, activation bias 2": (LOW_PASS_CHANNELS, 2.0),
}


def scenes(name: str, n: int, clean: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The first frames (n, H, W, 3) uint8 of n fresh scenes of task `name` and the positions they drew: entry ->
    (n, 2) m."""
    task = find_task(name, ENV_VERSIONS[-1])
    env = task.make_env(task.conditions[0] if task.conditions else None, task.max_steps)
    if clean:
        env.robot = dataclasses.replace(env.robot, **dict.fromkeys(SENSING, 0.0))
    frames, positions = [], {}
    try:
        for i in range(n):
            observation, _ = env.reset(seed=SCENE_SEED + i)
            frames.append(observation[env.image_key])
            for key, value in env.scene.items():
                if key.endswith("_xy"):
                    positions.setdefault(key, []).append(np.asarray(value, np.float64))
    finally:
        env.close()
    return np.stack(frames), {key: np.stack(value) for key, value in positions.items()}


def readouts(frames: np.ndarray, k: int, weights: str) -> dict[str, np.ndarray]:
    """name -> (m, f) float64: the features `cnep extract --weights weights` gives (random weights calibrated on the
    first k frames) and the frames as PIXELS x PIXELS pixels."""
    extractor = FeatureExtractor(weights=weights, backend="eager", threads=1)
    if extractor.needs_calibration:
        extractor.calibrate(frames[:k])
    small = [cv2.resize(f, (PIXELS, PIXELS), interpolation=cv2.INTER_AREA) for f in frames]
    return {
        f"features ({extractor.weights_name.split(':')[0]})": extractor(frames).astype(np.float64),
        f"pixels {PIXELS}x{PIXELS}": np.stack(small).reshape(len(frames), -1).astype(np.float64),
    }


def ablated(frames: np.ndarray, k: int, variants: dict = ABLATION) -> dict[str, np.ndarray]:
    """name -> (m, f) float64: the features of seed 0's random weights built as each of `variants` says (as
    ABLATION's entries), calibrated on the first k frames (run eagerly: the network `cnep extract` runs)."""
    pixels = resize_frames(frames)
    out = {}
    batches = [pixels[i : min(i + CALIBRATION_BATCH, k)] for i in range(0, k, CALIBRATION_BATCH)]
    for name, (channels, bias) in variants.items():
        features = seeded_features(0)
        if channels is not None:
            low_pass(features, channels)
        net = FeatureNet(features, "cells")
        calibrate_random_network(net, batches, activation_bias=bias)
        with torch.inference_mode():
            out[name] = net(torch.from_numpy(pixels)).numpy().astype(np.float64)
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("task", choices=TASK_NAMES, help="the task whose scenes are probed")
    parser.add_argument("--scenes", type=int, default=240, help="fresh scenes, fitting ones included (default 240)")
    parser.add_argument("--fit", type=int, default=40, help="scenes the probe is fitted on (default 40)")
    parser.add_argument("--clean", action="store_true", help="without the robot's camera, light and pixel noise")
    parser.add_argument("--weights", default="random", help="the feature network's, as `cnep extract` takes them")
    parser.add_argument("--ablation", action="store_true", help="also random weights without parts of their making")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args(argv)
    if not FOLDS <= args.fit < args.scenes:
        parser.error(f"--fit must be at least {FOLDS} and below --scenes, got {args.fit} of {args.scenes}")
    cnep.sim.require_extra()
    frames, positions = scenes(args.task, args.scenes, args.clean)
    inputs = readouts(frames, args.fit, args.weights) | (ablated(frames, args.fit) if args.ablation else {})
    rows = [
        {"position": key, "readout": name, **probe(x, y, args.fit)}
        for name, x in inputs.items()
        for key, y in positions.items()
    ]
    sensing = "without the robot's sensing" if args.clean else "with the robot's sensing"
    print(f"{args.task}, {sensing}: fitted on {args.fit} scenes, scored on {args.scenes - args.fit}\n")
    print("| position | readout | probe, median | the mean, median |\n|---|---|---|---|")
    for row in rows:
        print(f"| {row['position']} | {row['readout']} | {row['probe_cm']:.1f} cm | {row['mean_cm']:.1f} cm |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
