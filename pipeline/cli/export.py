"""`cnep export CHECKPOINT --out DIR [--extractor FILE] [--int8 --calibration DEMOS...]`: a policy without torch."""

from __future__ import annotations

import argparse

from cnep.models.config import ConditioningOverrides
from cnep.pipeline.cli.fields import add_options, build, chosen_options, options

CONDITIONING = "conditioning"  # the options' group in --help
HELP = "export a checkpoint as a policy folder (ONNX graphs + manifest + runtime) that runs without torch"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", help="checkpoint folder written by `cnep train` (read only)")
    parser.add_argument("--out", required=True, metavar="DIR", help="the policy folder to write (must not exist)")
    parser.add_argument(
        "--extractor",
        metavar="FILE",
        default=None,
        help="weights file the training features were made with (`cnep extract --save-weights`, the demo's "
        "extractor.pt); default: ImageNet weights",
    )
    parser.add_argument(
        "--int8", action="store_true", help="also write the int8 feature graph (quantised on --calibration frames)"
    )
    parser.add_argument(
        "--calibration",
        nargs="+",
        metavar="DEMOS",
        default=(),
        help="demonstration files or folders whose frames calibrate the int8 graph (e.g. the training demos)",
    )
    add_time_base(parser, "default: the checkpoint's, from its training demonstrations")
    add_conditioning(parser)
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --out policy folder (one `cnep export` wrote: its manifest names every file in it, "
        "unchanged)",
    )


def add_conditioning(parser: argparse.ArgumentParser) -> None:
    """The options that replace a policy's own conditioning settings (`cnep export`, `cnep run`, `cnep replay`)."""
    add_options(parser, options(ConditioningOverrides, CONDITIONING))


def conditioning_given(args: argparse.Namespace) -> ConditioningOverrides:
    """The conditioning settings given on the parsed command line `args`."""
    return build(ConditioningOverrides, chosen_options(ConditioningOverrides, args))


def time_base(text: str):
    """A `--time-base DURATION_S,PERIOD_S` value as a runtime.TimeBase."""
    from cnep.runtime.errors import PolicyError
    from cnep.runtime.timebase import TimeBase

    try:
        return TimeBase.parse(text)
    except PolicyError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_time_base(parser: argparse.ArgumentParser, default: str) -> None:
    """The `--time-base` option of `cnep export` and `cnep run`."""
    parser.add_argument(
        "--time-base",
        type=time_base,
        metavar="DURATION_S,PERIOD_S",
        help=f"the episode's length and step period in seconds, which map the robot's clock onto the model's "
        f"phase (t = seconds / DURATION_S); {default}",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cnep.models.checkpoint import CONFIG_FILE, read_checkpoint_config
    from cnep.pipeline.contract import refuse_existing
    from cnep.pipeline.export.config import ExportConfig
    from cnep.pipeline.inputs import existing_files, find_demonstration_files
    from cnep.pipeline.run.config import conditioning_line
    from cnep.pipeline.train.config import checkpoint_conditioning

    config = ExportConfig(
        checkpoint=Path(args.checkpoint),
        out=Path(args.out),
        extractor=Path(args.extractor) if args.extractor else None,
        int8=args.int8,
        calibration=tuple(Path(p) for p in args.calibration),
        time_base=args.time_base,
        conditioning=conditioning_given(args),
        force=args.force,
        quiet=args.quiet,
    )
    checkpoint = read_checkpoint_config(
        config.checkpoint
    )  # inputs are refused before torch and onnx load with the stage
    if config.extractor is not None:
        existing_files([config.extractor], "the weights file the training features were made with")
    find_demonstration_files(config.calibration)
    refuse_existing([config.out], config.force, what="exported policy")
    from cnep.pipeline.progress import heartbeat

    with heartbeat("loading torch and the export stage", args.quiet):
        from cnep.pipeline.export.stage import export
        from cnep.runtime import read_manifest

    out = export(config)
    manifest = read_manifest(out)
    own = checkpoint_conditioning(checkpoint, config.checkpoint / CONFIG_FILE)
    for name in [*(f["file"] for f in manifest.features.values()), *manifest.graphs.values()]:
        print(f"{out / name}: {(out / name).stat().st_size / 1e6:.1f} MB")
    print(conditioning_line(own, config.conditioning, "the checkpoint's"))
    print(
        f"exported {config.checkpoint} -> {out}; run it with `cnep run {out} RECORDING... --out run.rrd`, or on a "
        f"robot without torch: `pip install {out}/runtime` and `cnep.runtime.load_policy('{out}')`"
    )
    return 0
