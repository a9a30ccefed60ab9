"""`cnep evaluate [--table comparison|ablation|experts|commitment|all] [--quick]`: the paper's tables, measured."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.executor import add_executor, executor_of
from cnep.pipeline.evaluate.constants import SET_TITLES

HELP = "reproduce the paper's tables (CNEP vs CNMP, ProMP, GMM-GMR, nearest demo) on its synthetic sets"

TABLE_CHOICES = ("comparison", "ablation", "experts", "commitment", "all")
SET_CHOICES = tuple(SET_TITLES)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--table",
        choices=TABLE_CHOICES,
        default="comparison",
        help="which table to measure (default: comparison, the CNEP vs CNMP and baselines table; "
        "commitment: conditioned only on points several modes share, does a model return one "
        "demonstrated mode or their average)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a few minutes: fewer training steps, one seed, the bimodal and 4-mode sets, 20 queries",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="seeds per cell (default 1; the paper's tables in docs/results.md use 2)",
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="training steps per network on every set (default: 4000 on the unimodal and bimodal sets, 10000 on 4 "
        "and 6 modes; 1500 with --quick)",
    )
    parser.add_argument(
        "--patience",
        type=int,
        default=None,
        help="stop a network after N validations (every 500 steps) without improvement, keeping its best "
        "(default 4; 0: train every network for all its steps)",
    )
    parser.add_argument(
        "--sets",
        nargs="+",
        choices=SET_CHOICES,
        default=None,
        metavar="SET",
        help=f"only these data sets of each table ({', '.join(SET_CHOICES)}; default: all of the table's)",
    )
    parser.add_argument(
        "--queries", type=int, default=None, help="queries per protocol and set (default 50; 20 with --quick)"
    )
    parser.add_argument("--out", default="cnep-evaluation", help="folder for the Markdown, JSON and PNG outputs")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes, one thread each (0: this process only)")
    add_executor(parser, "the fits", "--jobs")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace tables and figures already in --out (only those cnep evaluate recorded writing)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cnep.pipeline.evaluate.constants import PATIENCE, QUICK_NOTE, QUICK_QUERIES, QUICK_SEEDS, QUICK_STEPS, TABLES
    from cnep.pipeline.evaluate.stage import EvaluateConfig, evaluate

    kind, address = executor_of(args)
    config = EvaluateConfig(
        tables=TABLES if args.table == "all" else (args.table,),
        quick=args.quick,
        seeds=args.seeds,
        steps=args.steps,
        queries=args.queries,
        sets=tuple(args.sets) if args.sets else None,
        patience=PATIENCE if args.patience is None else args.patience or None,  # 0: off
        out=Path(args.out),
        jobs=args.jobs,
        figures=not args.no_figures,
        force=args.force,
        quiet=args.quiet,
        executor=kind,
        address=address,
    )
    written = evaluate(config)
    for path in written.values():
        print(path.read_text())
    print("written: " + ", ".join(str(p) for p in written.values()) + f" (+ JSON; figures in {config.out / 'figures'})")
    if config.quick:
        used = {"seeds": args.seeds or QUICK_SEEDS, "steps": args.steps or QUICK_STEPS}
        print(QUICK_NOTE.format(**used, queries=args.queries or QUICK_QUERIES))
    return 0
