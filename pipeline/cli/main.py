"""The `cnep` command: one subcommand per pipeline stage.

Each subcommand lives in `pipeline/cli/<name>.py` and exposes `HELP`, `add_arguments(parser)`
and `run(args) -> int`. Those modules import only argparse at module level, so `cnep --help` stays
instant; torch, rerun and friends are imported inside `run`.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import re
import signal
import sys
import threading

NUMBERS = re.compile(r"^-\d*\.?\d+(e[-+]?\d+)?(,[-+]?\d*\.?\d+(e[-+]?\d+)?)*$", re.IGNORECASE)  # -1, -.5, -1,0.05

# Subcommand names, in pipeline order; each is the module under pipeline.cli of that name (`-` read as `_`).
COMMANDS = (
    "ingest",
    "to-lerobot",
    "inspect",
    "repair",
    "extract",
    "train",
    "replay",
    "export",
    "run",
    "view",
    "evaluate",
    "demo",
    "sim",
)


def _available_commands() -> list[tuple[str, object]]:
    found = []
    for name in COMMANDS:
        module_name = f"cnep.pipeline.cli.{name.replace('-', '_')}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue  # that stage is not part of this build yet
        found.append((name, module))
    return found


class _Parser(argparse.ArgumentParser):
    """argparse, with a value that starts with a minus sign and lists numbers (`--time-base -1,0.05`) read as a value,
    as `-1` already is, rather than as an unknown option (the subcommands' parsers are of this class too)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NUMBERS


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="cnep",
        description="Learn multimodal movement primitives (CNEP) from recorded demonstrations.",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors, no progress bars")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging, and the traceback of an error")
    parser.add_argument("--version", action=_Version, nargs=0, help="show the installed version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in _available_commands():
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """The `cnep` command on `argv` (None: the process's command line); returns the exit status.

    SIGINT and SIGTERM are handled from here on (pipeline.contract): with argv None, to the process's end (a
    signal after the command finished ends it at once with one line); with argv given, until this returns.
    """
    from cnep.pipeline.contract import handle_signals, interrupted_line, run_command

    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    finished = handle_signals()
    try:
        try:
            args = build_parser().parse_args(argv)
        except KeyboardInterrupt as exc:
            return interrupted_line("", exc)
        level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO
        logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
        if not args.verbose:  # torch's own INFO lines (cache statistics at exit) are not the user's business
            logging.getLogger("torch").setLevel(logging.WARNING)
        status = run_command(args.command, lambda: args._run(args), verbose=args.verbose)
        if argv is None:
            finished(args.command, status)
        return status
    finally:
        if argv is not None and threading.current_thread() is threading.main_thread():  # called in-process
            for signum, handler in saved.items():
                signal.signal(signum, handler)


class _Version(argparse.Action):
    """`--version`: the version is looked up only when asked for (importlib.metadata costs a tenth of a second)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"{parser.prog} {_version()}")
        parser.exit()


def _version() -> str:
    """The installed cnep-pipeline version (pyproject.toml)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cnep-pipeline")
    except PackageNotFoundError:
        return "unknown (not installed)"


if __name__ == "__main__":
    sys.exit(main())
