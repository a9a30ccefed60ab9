"""Where does a model plan the grasp on demonstrations it never trained on? Its planned grasp against the recorded one.

    python examples/grasp_probe.py CHECKPOINT HELD_OUT [HELD_OUT ...] [--before K [K ...]] [--json FILE]

CHECKPOINT is a `cnep train` folder of a model that reads image features and predicts the pose and a gripper;
each HELD_OUT a trajectory file or folder (`cnep extract`, with the checkpoint's extractor) of demonstrations of the
same task that the model never trained on. A demonstration's grasp is its first step whose recorded gripper the
checkpoint's two-state command (runtime.gripper) reads closed; the grasp's position is the pose's x and y there.

The model is conditioned as its policy is (the checkpoint's conditioning: its first `anchors` steps and its latest
`window`, models.online.OnlineConditioner) on the steps up to a read: the first step, and K steps before the grasp
for each --before K. The active expert's predicted pose at the grasp's time is the planned grasp; the median over
the demonstrations of its horizontal distance from the recorded grasp is the model's error (cm). Beside it, what the
frames allow and what ignoring them gives: a ridge probe (examples/probes.py) from the read step's image features to
the grasp's position, fitted on the checkpoint's training demonstrations (its config.json's files) and scored on the
held-out ones, and the training demonstrations' mean grasp position.

A policy cannot grasp more precisely than it plans the grasp on scenes it never saw; where the model misses by more
than the probe, the model, not the frames, loses the object's position. Prints one markdown row per read; --json
FILE writes them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from probes import FOLDS, probe

from cnep.models import OnlineConditioner
from cnep.pipeline.errors import USER_ERRORS, PipelineError
from cnep.pipeline.inputs import TRAJECTORIES, mcap_files
from cnep.pipeline.train.checkpoint import TrainedModel, load_trained
from cnep.pipeline.train.config import checkpoint_conditioning
from cnep.recordings import read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_GRIPPER, BLOCK_POSE_XYZ
from cnep.runtime.gripper import GripperCommand

BEFORE = (12, 6, 1)  # the reads before the grasp, in steps


def grasp_step(gripper: np.ndarray, command: GripperCommand) -> int | None:
    """The first step whose gripper value (T,) `command` reads closed, from the open command it starts at (None: it
    never closes)."""
    previous = command.nearest(float(gripper[0]))
    for k, value in enumerate(gripper):
        previous = command.command(float(value), previous)
        if command.is_closed(previous):
            return k
    return None


class Demonstration:
    """One demonstration's rows as the model takes them, its features and grasp: the step and its x, y (m)."""

    def __init__(self, path: Path, trained: TrainedModel, command: GripperCommand) -> None:
        trajectory = read_trajectory(path)
        missing = [b for b in (BLOCK_FEATURES, BLOCK_POSE_XYZ, BLOCK_GRIPPER) if b not in trajectory.blocks]
        if missing:
            raise PipelineError(f"{path}: the trajectory has no {', '.join(missing)} columns; the probe needs them")
        block = {name: trajectory.data[:, a:b] for name, (a, b) in trajectory.blocks.items()}
        self.rows = trained.rows(trajectory, path)
        self.features = block[BLOCK_FEATURES].astype(np.float64)
        self.grasp = grasp_step(block[BLOCK_GRIPPER][:, 0], command)
        self.xy = block[BLOCK_POSE_XYZ][self.grasp, :2].astype(np.float64) if self.grasp is not None else None

    def read_at(self, before: int | None) -> int | None:
        """The read step: the first (`before` None), or `before` steps before the grasp (None where that is before
        the first step)."""
        if before is None:
            return 0
        return self.grasp - before if self.grasp >= before else None


def planned_grasp(trained: TrainedModel, online: OnlineConditioner, demo: Demonstration, read: int) -> np.ndarray:
    """The active expert's x, y (m) at the grasp's time, conditioned on `demo`'s steps up to `read` as the policy is."""
    xyz = trained.mapping.predicted_xyz(trained.model)
    online.reset()
    for k in range(read + 1):
        online.step(demo.rows[k])
    mean, _ = online.predict(online.time_of([demo.grasp]))
    return mean[0, xyz[:2]].astype(np.float64)


def measure(trained: TrainedModel, held_out: list[Demonstration], training: list[Demonstration], before) -> list:
    """One row per read (the first step, then each of `before`): the model's, the probe's and the mean's median
    errors (cm) over the held-out demonstrations that reach that read (a read that fewer than FOLDS training
    demonstrations reach, which the probe's cross-validation needs, has no row)."""
    policy = checkpoint_conditioning(trained.config, trained.path)
    rows = []
    for b in (None, *before):
        tests = [d for d in held_out if d.read_at(b) is not None]
        fits = [d for d in training if d.read_at(b) is not None]
        if not tests or len(fits) < FOLDS:
            continue
        errors = [
            np.linalg.norm(
                planned_grasp(trained, OnlineConditioner(trained.model, len(d.rows), policy), d, d.read_at(b)) - d.xy
            )
            for d in tests
        ]
        x = np.stack([d.features[d.read_at(b)] for d in (*fits, *tests)])
        y = np.stack([d.xy for d in (*fits, *tests)])
        rows.append(
            {
                "read": "the first step" if b is None else f"{b} step{'s' * (b != 1)} before the grasp",
                "demonstrations": len(tests),
                "model_cm": round(100 * float(np.median(errors)), 2),
                **probe(x, y, len(fits)),
            }
        )
    return rows


def demonstrations(paths, trained: TrainedModel, command: GripperCommand) -> list[Demonstration]:
    """The demonstrations in `paths` (files or folders) that grasp."""
    files = [f for p in paths for f in mcap_files(Path(p), TRAJECTORIES)]
    return [d for d in (Demonstration(f, trained, command) for f in files) if d.grasp is not None]


def probe_checkpoint(checkpoint: Path, held_out: list[Path], before) -> list[dict]:
    """The rows (`measure`) of the checkpoint on the held-out trajectory files or folders; PipelineError for a
    checkpoint without a pose or a gripper command, as for any input the stages refuse."""
    trained = load_trained(checkpoint)
    if not trained.config.get("gripper") or trained.mapping.predicted_xyz(trained.model) is None:
        raise PipelineError(f"{checkpoint}: the model predicts no pose or has no gripper command; the probe needs both")
    command = GripperCommand.from_dict(trained.config["gripper"])
    fitted = [Path(f["path"]) for f in trained.config.get("files", []) if f.get("split") == "train"]
    tests = demonstrations(held_out, trained, command)
    if not tests:
        raise PipelineError(f"no demonstration in {', '.join(map(str, held_out))} closes the gripper: nothing to probe")
    return measure(trained, tests, demonstrations(fitted, trained, command), before)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a `cnep train` folder")
    parser.add_argument("held_out", type=Path, nargs="+", help="trajectory files or folders it never trained on")
    parser.add_argument("--before", type=int, nargs="+", default=list(BEFORE), help="steps before the grasp to read at")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args(argv)
    if min(args.before) < 0:
        parser.error(f"--before counts steps before the grasp, >= 0; got {min(args.before)}")
    try:
        rows = probe_checkpoint(args.checkpoint, args.held_out, args.before)
    except USER_ERRORS as exc:
        parser.error(str(exc))
    print("| read | held out | model | ridge on the features | the mean |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['read']} | {r['demonstrations']} | {r['model_cm']} cm | {r['probe_cm']} cm | {r['mean_cm']} cm |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
