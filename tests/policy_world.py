"""One small trained policy for the runtime, export and run tests, built once per session through the CLI.

Demonstrations with camera frames -> `cnep extract` (seeded random weights, saved) -> `cnep train` (layout
`scene`: features, pose and gripper observed, pose and gripper predicted; and a `motion` model) -> `cnep
export` (fp32 and int8 features). Small enough for CI: 4 demonstrations of 12 steps, 32 x 24 frames, 2
experts of width 16, 30 training steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cnep.pipeline.cli.main import main
from cnep.recordings import write_demonstration
from tests.recordings.factories import demonstration_factory

STEPS = 12
TRAINING = [
    "--steps",
    "30",
    "--val-every",
    "10",
    "--encoder-widths",
    "16,16",
    "--expert-widths",
    "16,16",
    "--batch-size",
    "4",
    "--experts",
    "2",
    "--warmup-steps",
    "6",
]


@dataclass(frozen=True)
class PolicyWorld:
    """Inputs shared by the tests (never written to)."""

    demos: Path  # folder of 3 training demonstrations with frames
    heldout: Path  # one more demonstration, never trained on
    extractor: Path  # the extractor's weights (random, calibrated on the demos)
    checkpoint: Path  # layout scene: sees the camera
    motion_checkpoint: Path  # layout motion: pose and gripper only
    exported: Path  # `cnep export checkpoint --int8`: fp32 and int8 feature graphs


def build_policy_world(root: Path) -> PolicyWorld:
    demos = root / "demos"
    demos.mkdir(parents=True)
    for i in range(3):
        demo = demonstration_factory(STEPS, frames=True, seed=i, episode_id=f"d{i}", frame_size=32)
        write_demonstration(demos / f"d{i}.mcap", demo)
    heldout = root / "heldout.mcap"
    write_demonstration(heldout, demonstration_factory(STEPS, frames=True, seed=7, episode_id="h", frame_size=32))
    extractor = root / "extractor.pt"
    cli("extract", demos, "--out", root / "trajs", "--weights", "random", "--save-weights", extractor, "--threads", "1")
    cli("train", root / "trajs", "--out", root / "ckpt", "--layout", "scene", *TRAINING)
    cli("train", root / "trajs", "--out", root / "motion", "--layout", "motion", *TRAINING)
    exported = root / "exported"
    cli("export", root / "ckpt", "--out", exported, "--extractor", extractor, "--int8", "--calibration", demos)
    return PolicyWorld(demos, heldout, extractor, root / "ckpt", root / "motion", exported)


def cli(*argv) -> None:
    code = main(["-q", *map(str, argv)])
    assert code == 0, f"cnep {' '.join(map(str, argv))} exited {code}"
