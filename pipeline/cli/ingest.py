"""`cnep ingest SRC --out DIR`: raw recordings -> demonstration MCAP files."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.fields import default_of
from cnep.recordings.lerobot_columns import GRIPPER_SOURCES, LerobotMapping

HELP = (
    "convert recordings (video/images + CSV, motion-only CSV, a robot's MCAP or ROS bag, a LeRobot dataset) into "
    "demonstration MCAP files"
)

COLUMN_KEYS = "time time_unit x y z qx qy qz qw gripper"


def _key_value(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=NAME, got {text!r}")
    return key.strip(), value.strip()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("src", help="a recording folder, a CSV file or an MCAP file (read only)")
    parser.add_argument("--out", required=True, help="folder for the demonstration files (created if missing)")
    parser.add_argument(
        "--force",
        action="store_true",
        help="redo demonstration files that already exist in --out (only files `cnep ingest` recorded writing)",
    )
    parser.add_argument(
        "--keep-going",
        action="store_true",
        help="skip recordings that fail, write the others, and list the skipped ones at the end (exit 2)",
    )
    parser.add_argument("--task", default="", help="task label stored in each file's episode metadata")
    g = parser.add_argument_group(
        "CSV (columns found by their usual names: t/time/timestamp, x y z or p_x..., qx... or q_x..., gripper; "
        "the time unit stated, named in the header or inferred from the rate)"
    )
    g.add_argument(
        "--column",
        action="append",
        type=_key_value,
        default=[],
        metavar="KEY=NAME",
        help=f"map a key to a CSV column (keys: {COLUMN_KEYS}); time_unit=s|ms|us|ns; gripper= for none; repeatable",
    )
    g.add_argument(
        "--frame-rate", type=float, default=None, metavar="HZ", help="camera rate when frames are not one per CSV row"
    )
    g.add_argument(
        "--frame-offset-ms",
        type=float,
        default=0.0,
        metavar="MS",
        help="time of the first frame after the first CSV row",
    )
    m = parser.add_argument_group("MCAP input (Foxglove or ROS 2 schemas) and ROS bags (ROS 1 .bag, ROS 2 bag folders)")
    m.add_argument("--image-topic", default="/camera/rgb", help='image topic ("" for motion-only)')
    m.add_argument("--pose-topic", default="/ee/pose", help="end-effector pose topic")
    m.add_argument("--gripper-topic", default="/gripper", help='gripper JointStates topic ("" for none)')
    m.add_argument("--gripper-joint", default="gripper", help="joint name of the gripper in that topic")
    m.add_argument(
        "--pose-frame",
        default="",
        metavar="FRAME",
        help="ROS bags with a tf pose topic (e.g. --pose-topic /tf): the child frame to use",
    )
    r = parser.add_argument_group("LeRobot dataset (v2.1 or v3.0; needs the `lerobot` extra)")
    r.add_argument(
        "--format",
        choices=("auto", "lerobot"),
        default="auto",
        help="auto: a LeRobot dataset if SRC holds meta/info.json, else the files found (default: auto)",
    )
    r.add_argument(
        "--camera",
        default=None,
        metavar="KEY",
        help='camera feature, e.g. observation.images.top (default: the only one; "" for motion-only)',
    )
    r.add_argument(
        "--state-column",
        default="observation.state",
        metavar="COLUMN",
        help="vector column holding pose and gripper (default: observation.state)",
    )
    r.add_argument(
        "--pose",
        default=None,
        metavar="A,B,...",
        help="7 entries x,y,z,qx,qy,qz,qw or 6 x,y,z,roll,pitch,yaw (radians) of that column, as names from "
        "info.json or indices (default: entries named so)",
    )
    r.add_argument(
        "--gripper",
        default=None,
        metavar="NAME|INDEX",
        help='gripper entry of that column (default: the entry named gripper; "" for none)',
    )
    r.add_argument(
        "--gripper-from",
        choices=GRIPPER_SOURCES,
        default=default_of(LerobotMapping, "gripper_from"),
        help="action: the gripper entry of the dataset's action where it names one (the commanded open/close, what "
        "a policy learns), else the state's; state: the state's (the measured opening) (default: %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cnep.pipeline.ingest.stage import IngestConfig, ingest
    from cnep.recordings.adapters import FrameTiming
    from cnep.recordings.csv_motion import CsvColumns
    from cnep.recordings.mcap_source import McapTopics

    config = IngestConfig(
        src=Path(args.src),
        out=Path(args.out),
        columns=CsvColumns.from_overrides(dict(args.column)),
        timing=FrameTiming(frame_rate=args.frame_rate, offset_ms=args.frame_offset_ms),
        topics=McapTopics(
            image=args.image_topic,
            pose=args.pose_topic,
            gripper=args.gripper_topic,
            gripper_joint=args.gripper_joint,
            pose_frame=args.pose_frame,
        ),
        task=args.task,
        force=args.force,
        keep_going=args.keep_going,
        quiet=args.quiet,
        format=args.format,
        lerobot=LerobotMapping(
            camera=args.camera,
            state=args.state_column,
            gripper=args.gripper,
            gripper_from=args.gripper_from,
            pose=tuple(p.strip() for p in args.pose.split(",")) if args.pose else None,
        ),
    )
    done = ingest(config)
    with_frames = sum(d.has_frames for d in done)
    skipped = sum(d.skipped for d in done)
    print(
        f"ingested {len(done) - skipped} demonstration(s) into {config.out} ({skipped} up to date; "
        f"{with_frames} with frames, {len(done) - with_frames} motion-only, {sum(d.n_steps for d in done)} steps)"
    )
    return 0
