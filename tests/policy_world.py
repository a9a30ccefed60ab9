"""The policies of the runtime, export and run tests, built once per session on the quick demo's outputs.

The quick demo (tests/conftest.py `quick_demo`) gives a checkpoint of layout `scene` (features, pose and
gripper observed, pose and gripper predicted; 4 experts of 128 x 128), its extractor's weights and
demonstrations with camera frames. Added here through the CLI: `cnep export` of that checkpoint with fp32
and int8 features (the int8 graph calibrated on one training demonstration), and a small `motion` model
(pose and gripper only) trained on the demo's training trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cnep.pipeline.cli.main import main

MOTION_TRAINING = ["--layout", "motion", "--steps", "30", "--val-every", "10", "--warmup-steps", "6"]
MOTION_TRAINING += ["--encoder-widths", "16,16", "--expert-widths", "16,16", "--batch-size", "4", "--experts", "2"]


@dataclass(frozen=True)
class PolicyWorld:
    """Inputs shared by the tests (never written to)."""

    demos: Path  # the demo's training demonstrations (with frames)
    heldout: Path  # one held-out demonstration, never trained on
    extractor: Path  # the weights the demo's features were made with
    checkpoint: Path  # layout scene: sees the camera
    motion_checkpoint: Path  # layout motion: pose and gripper only
    exported: Path  # `cnep export checkpoint --int8`: fp32 and int8 feature graphs

    @classmethod
    def of(cls, demo: Path, root: Path) -> PolicyWorld:
        """The world on the quick demo's outputs in `demo`, what it adds under `root` (build_policy_world)."""
        demos, heldout = demo / "demos" / "train", sorted((demo / "demos" / "heldout").glob("*.mcap"))[0]
        checkpoint = demo / "checkpoints" / "cnep"
        return cls(demos, heldout, demo / "extractor.pt", checkpoint, root / "motion", root / "exported")


def build_policy_world(demo: Path, root: Path) -> None:
    """Write what the world adds to the quick demo's outputs in `demo` under `root`."""
    w = PolicyWorld.of(demo, root)
    cli("train", demo / "trajectories" / "train", "--out", w.motion_checkpoint, *MOTION_TRAINING)
    calibration = sorted(w.demos.glob("*.mcap"))[0]
    cli("export", w.checkpoint, "--out", w.exported, "--extractor", w.extractor, "--int8", "--calibration", calibration)


def cli(*argv) -> None:
    code = main(["-q", *map(str, argv)])
    assert code == 0, f"cnep {' '.join(map(str, argv))} exited {code}"
