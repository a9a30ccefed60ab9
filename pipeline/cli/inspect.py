"""`cnep inspect FILE...`: topics, counts, rates, metadata, layout, completeness of MCAP files."""

from __future__ import annotations

import argparse
import sys

HELP = "show what MCAP files hold (topics, message counts, duration, rate, metadata, layout) and whether they are complete"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="MCAP files (read only)")


def run(args: argparse.Namespace) -> int:
    """Exit 0 if every file is complete (and, for cnep files, accepted), 1 if not, 2 if one is unreadable."""
    from recordings.errors import RecordingError
    from recordings.inspection import format_report, inspect_file

    status = 0
    for path in args.files:
        try:
            report = inspect_file(path)
        except RecordingError as exc:
            print(f"cnep inspect: error: {exc}", file=sys.stderr)
            status = 2
            continue
        print(format_report(report))
        if not report.complete or (report.check not in (None, "ok")):
            status = max(status, 1)
    return status
