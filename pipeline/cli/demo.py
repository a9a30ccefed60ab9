"""`cnep demo [--out DIR] [--quick]`: the whole pipeline on the built-in tabletop demonstrations."""

from __future__ import annotations

import argparse

from cnep.models.config import ASSIGNMENTS
from cnep.pipeline.cli.fields import default_of
from cnep.pipeline.demo.config import DemoConfig

DEFAULT_OUT = "cnep-demo"
HELP = (
    "run the whole pipeline on built-in synthetic tabletop demonstrations: generate, ingest, extract, train "
    "CNEP and CNMP, replay to Rerun, print which expert took which behaviour"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    seed, assignment, precision, weights = (
        default_of(DemoConfig, name) for name in ("seed", "assignment", "precision", "weights")
    )
    parser.add_argument(
        "--out",
        default=None,
        help=f"new or empty folder for everything (default: the first of "
        f"{DEFAULT_OUT}, {DEFAULT_OUT}-2, ... that is new or empty)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a small, fast variant (for CI): fewer demonstrations, shorter episodes, a few training steps",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=seed,
        help=f"seed of every random draw (default {seed})",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="use a non-empty --out folder: first delete what an earlier demo wrote there (refused if its folders "
        "hold anything else)",
    )
    parser.add_argument(
        "--assignment",
        choices=ASSIGNMENTS,
        default=assignment,
        help="the CNEP's reconstruction term: the paper's gate-weighted NLL, the mixture likelihood, "
        "the annealed posterior assignment, or annealed with bounded rather than equal expert "
        f"shares, faded out (default {assignment}: docs/concepts.md)",
    )
    parser.add_argument(
        "--precision",
        choices=("fp32", "int8"),
        default=precision,
        help=f"feature extraction precision (default {precision}; int8 as `cnep extract --precision int8`)",
    )
    parser.add_argument(
        "--weights",
        default=weights,
        help="the feature network's weights: `auto`, ImageNet's where they can be had (the torch hub cache, "
        "$CNEP_MOBILENET_WEIGHTS, or a download into the cache) and else seeded random weights calibrated on the "
        "training frames, with a warning saying why; `imagenet`, the same but an error instead of random weights; "
        f"`random`; or the path of a MobileNet-v2 state dict (default {weights})",
    )
    parser.add_argument(
        "--offline",
        action="store_true",
        help="never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)",
    )


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from cnep.pipeline.demo.config import AUTO_WEIGHTS, IMAGENET_WEIGHTS, RANDOM_WEIGHTS
    from cnep.pipeline.inputs import existing_files

    if args.weights not in (
        AUTO_WEIGHTS,
        IMAGENET_WEIGHTS,
        RANDOM_WEIGHTS,
    ):  # refused before torch loads with the stage
        existing_files([Path(args.weights)], "`auto`, `imagenet`, `random` or a MobileNet-v2 state dict")
    from cnep.pipeline.demo.report import format_summary
    from cnep.pipeline.demo.stage import run_demo

    start = time.perf_counter()
    out = Path(args.out) if args.out is not None else free_folder(Path(DEFAULT_OUT))
    result = run_demo(
        DemoConfig(
            out=out,
            quick=args.quick,
            seed=args.seed,
            force=args.force,
            quiet=args.quiet,
            assignment=args.assignment,
            precision=args.precision,
            weights=args.weights,
            offline=args.offline,
        )
    )
    print(format_summary(result))
    print(f"cnep demo: done in {time.perf_counter() - start:.1f} s")
    return 0


def free_folder(base):
    """`base`, or `base-2`, `base-3`, ...: the first that does not exist or is empty (a new run never mixes with an
    old one)."""
    from itertools import chain, count

    for candidate in chain([base], (base.with_name(f"{base.name}-{k}") for k in count(2))):
        if not candidate.exists() or (candidate.is_dir() and not any(candidate.iterdir())):
            return candidate
