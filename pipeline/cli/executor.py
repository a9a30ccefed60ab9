"""The `--executor KIND [ADDRESS]` option of the commands that spread their work over processes or a cluster (`cnep
evaluate`, `cnep sim grid`): where it runs (pipeline.evaluate.executors), parsed alike for both."""

from __future__ import annotations

import argparse

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.constants import EXECUTORS


def add_executor(parser: argparse.ArgumentParser, what: str, workers: str) -> None:
    """Add `--executor` to `parser`: `what` runs there (the fits, the cells); `workers`, the option that says how many
    local processes run it (`--jobs`, `--workers`)."""
    parser.add_argument(
        "--executor",
        nargs="+",
        default=(EXECUTORS[0],),
        metavar=("KIND", "ADDRESS"),
        help=f"where {what} run: local (default: {workers} processes here), or dask or ray followed by the cluster's "
        f"address (a Dask scheduler's tcp://host:8786, a Ray head's host:6379 or ray://host:10001; without one, a "
        f"cluster of {workers} processes on this machine); needs pip install 'cnep-pipeline[dask]' or '[ray]'",
    )


def executor_of(args: argparse.Namespace) -> tuple[str, str | None]:
    """(kind, address or None) of the parsed `--executor`; PipelineError for another kind or more than one address."""
    kind, *address = args.executor
    if kind not in EXECUTORS or len(address) > 1:
        raise PipelineError(f"--executor takes local, dask [ADDRESS] or ray [ADDRESS], got {' '.join(args.executor)}")
    return kind, address[0] if address else None
