"""`cnep to-lerobot DEMOS... --out DATASET`: demonstration files -> a LeRobot v3.0 dataset."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.fields import add_options, build, options
from cnep.pipeline.to_lerobot.config import ToLerobotConfig

HELP = "write demonstration files as a LeRobot v3.0 dataset (video frames, observation.state, action, episodes, tasks)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "demos", nargs="+", metavar="DEMOS", help="demonstration files or folders of them (read only), one episode each"
    )
    parser.add_argument("--out", required=True, metavar="DATASET", help="the dataset folder to write (must not exist)")
    add_options(parser, options(ToLerobotConfig), defaults={"fps": "the demonstrations' own, which must agree"})
    parser.add_argument("--force", action="store_true", help="replace an existing dataset that cnep wrote")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cnep.pipeline.contract import refuse_existing
    from cnep.pipeline.inputs import find_demonstration_files

    given = {
        option.name: getattr(args, option.name) for option in options(ToLerobotConfig) if hasattr(args, option.name)
    }
    config = build(
        ToLerobotConfig,
        given,
        demos=tuple(Path(p) for p in args.demos),
        out=Path(args.out),
        force=args.force,
        quiet=args.quiet,
    )
    find_demonstration_files(config.demos)  # the inputs are refused before pyarrow and PyAV load with the stage
    refuse_existing([config.out], config.force, what="LeRobot dataset")
    from cnep.pipeline.to_lerobot.stage import to_lerobot

    info = to_lerobot(config)
    camera = next((k for k, f in info["features"].items() if f["dtype"] == "video"), None)
    print(
        f"wrote {info['total_episodes']} episode(s), {info['total_frames']} frames at {info['fps']} Hz, "
        f"{info['total_tasks']} task(s) to {config.out} ({f'camera {camera}' if camera else 'motion only'}); "
        f"read it with `cnep ingest {config.out} --out DIR` or LeRobot's LeRobotDataset(repo_id, root='{config.out}')"
    )
    return 0
