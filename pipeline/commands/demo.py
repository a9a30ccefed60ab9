"""`cnep demo [--out DIR] [--quick]`: the whole pipeline on the built-in tabletop demonstrations."""

from __future__ import annotations

import argparse

HELP = ("run the whole pipeline on built-in synthetic tabletop demonstrations: generate, ingest, extract, train "
        "CNEP and CNMP, replay to Rerun, print which expert took which behaviour")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="cnep-demo", help="new or empty folder for everything (default: cnep-demo)")
    parser.add_argument("--quick", action="store_true", help="a small, fast variant (for CI): fewer demonstrations, "
                        "shorter episodes, a few training steps")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from pipeline.demo import DemoConfig, format_summary, run_demo

    start = time.perf_counter()
    result = run_demo(DemoConfig(out=Path(args.out), quick=args.quick, seed=args.seed, quiet=args.quiet))
    print(format_summary(result))
    print(f"cnep demo: done in {time.perf_counter() - start:.1f} s")
    return 0
