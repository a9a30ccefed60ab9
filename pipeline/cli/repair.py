"""`cnep repair IN OUT`: salvage the complete chunks and messages of a truncated MCAP file into a new valid file."""

from __future__ import annotations

import argparse

HELP = (
    "salvage every complete chunk and message of a truncated or damaged MCAP file into a new, valid file (IN is not "
    "modified)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("src", metavar="IN", help="the damaged MCAP file (read only)")
    parser.add_argument(
        "dst",
        metavar="OUT",
        help="where to write the salvaged file (must differ from IN; its folder is created if missing)",
    )
    parser.add_argument(
        "--force", action="store_true", help="replace OUT if it exists (only a file `cnep repair` recorded writing)"
    )


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from cnep.outputs import output_file, output_lock, writing_as
    from cnep.pipeline.contract import output_folder, refuse_existing
    from cnep.recordings.container import refuse_overwrite_input
    from cnep.recordings.repair import repair

    dst = Path(args.dst)
    refuse_overwrite_input(args.src, dst)
    with writing_as("repair"):
        refuse_existing([dst], args.force, "repaired file")
        with output_folder(dst.parent, "OUT's folder"), output_lock(dst), output_file(dst) as staged:
            report = replace(repair(args.src, staged), dst=dst)
    print(report.summary())
    return 0
