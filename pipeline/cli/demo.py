"""`cnep demo [--out DIR] [--quick]`: the whole pipeline on the built-in tabletop demonstrations."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.fields import add_options, build, options
from cnep.pipeline.demo.config import DemoConfig

DEFAULT_OUT = "cnep-demo"
HELP = (
    "run the whole pipeline on built-in synthetic tabletop demonstrations: generate, ingest, extract, train "
    "CNEP and CNMP, replay to Rerun, print which expert took which behaviour"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        default=None,
        help=f"new or empty folder for everything (default: the first of "
        f"{DEFAULT_OUT}, {DEFAULT_OUT}-2, ... that is new or empty)",
    )
    add_options(parser, options(DemoConfig))  # DemoConfig's fields and those of the CNEP's config it holds


def demo_config(args: argparse.Namespace) -> DemoConfig:
    """The demo's settings for the parsed command line: the options given, the others DemoConfig's defaults."""
    from pathlib import Path

    out = Path(args.out) if args.out is not None else free_folder(Path(DEFAULT_OUT))
    given = {option.name: getattr(args, option.name) for option in options(DemoConfig) if hasattr(args, option.name)}
    return build(DemoConfig, given, out=out, quiet=args.quiet)


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from cnep.pipeline.demo.config import AUTO_WEIGHTS, IMAGENET_WEIGHTS, RANDOM_WEIGHTS
    from cnep.pipeline.inputs import existing_files

    config = demo_config(args)
    if config.weights not in (AUTO_WEIGHTS, IMAGENET_WEIGHTS, RANDOM_WEIGHTS):  # refused before torch loads
        existing_files([Path(config.weights)], "`auto`, `imagenet`, `random` or a MobileNet-v2 state dict")
    from cnep.pipeline.progress import heartbeat

    with heartbeat("loading torch and the pipeline's stages", args.quiet):
        from cnep.pipeline.demo.report import format_summary
        from cnep.pipeline.demo.stage import run_demo

    start = time.perf_counter()
    result = run_demo(config)
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
