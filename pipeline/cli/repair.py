"""`cnep repair IN OUT`: salvage the complete chunks of a truncated MCAP file into a new valid file."""

from __future__ import annotations

import argparse

HELP = "salvage every complete chunk of a truncated or damaged MCAP file into a new, valid file (IN is not modified)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("src", metavar="IN", help="the damaged MCAP file (read only)")
    parser.add_argument("dst", metavar="OUT", help="where to write the salvaged file (must differ from IN)")


def run(args: argparse.Namespace) -> int:
    from recordings.repair import repair

    print(repair(args.src, args.dst).summary())
    return 0
