"""`cnep inspect FILE...`: topics, counts, rates, metadata, layout, completeness of MCAP files."""

from __future__ import annotations

import argparse
import sys

HELP = (
    "show what MCAP files hold (topics, message counts, duration, rate, metadata, layout) and whether they are complete"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="MCAP files (read only)")


def run(args: argparse.Namespace) -> int:
    """Exit 0 if every file is complete (and, for cnep files, accepted), else 2 after reporting on every file:
    the report on stdout, one line per refused file on stderr."""
    from cnep.pipeline.contract import EXIT_OK, EXIT_USER, error_line
    from cnep.recordings.errors import RecordingError
    from cnep.recordings.inspection import format_report, inspect_file

    status = EXIT_OK
    for path in args.files:
        try:
            report = inspect_file(path)
        except RecordingError as exc:
            print(error_line("inspect", exc), file=sys.stderr)
            status = EXIT_USER
            continue
        print(format_report(report), flush=True)
        if not report.complete or (report.check not in (None, "ok")):
            problem = (
                f"{report.path}: {report.problem}" if not report.complete else report.check.removeprefix("refused: ")
            )
            print(f"cnep inspect: error: {problem}", file=sys.stderr)
            status = EXIT_USER
    return status
