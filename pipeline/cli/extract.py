"""`cnep extract IN... --out DIR`: demonstration MCAP files -> trajectory MCAP files (1288-d steps)."""

from __future__ import annotations

import argparse

HELP = "turn demonstration files into trajectory files of MobileNet-v2 features + pose + gripper"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from cnep.models.schedule import FEW_DEMONSTRATIONS
    from cnep.perception.constants import DEFAULT_VIEWS, MAX_VIEWS

    parser.add_argument("inputs", nargs="+", metavar="IN", help="demonstration files or folders of them (read only)")
    parser.add_argument("--out", required=True, help="folder for the trajectory files (created if missing)")
    parser.add_argument(
        "--weights",
        default="imagenet",
        help="`imagenet` (torch hub cache, downloaded there if missing, or $CNEP_MOBILENET_WEIGHTS), "
        "`random` (seeded, calibrated on the inputs' frames) or the path of a MobileNet-v2 state "
        "dict (default: imagenet)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the random weights and the views (default 0)")
    parser.add_argument(
        "--views",
        type=int,
        default=None,
        help=f"also extract each demonstration's features under this many views of its frames (the camera a few "
        f"pixels moved, other light and pixel noise; at most {MAX_VIEWS}), which `cnep train` trains on beside "
        f"them; 0: none (default {DEFAULT_VIEWS} where fewer than {FEW_DEMONSTRATIONS} demonstrations are "
        f"extracted, else 0)",
    )
    parser.add_argument(
        "--save-weights",
        metavar="PATH",
        default=None,
        help="save the weights used (after calibration) to reuse them later with --weights PATH",
    )
    parser.add_argument(
        "--backend",
        default="auto",
        choices=("auto", "cuda", "onnxruntime", "openvino", "torchscript", "eager"),
        help="inference backend (default: the fastest available for the precision, cuda where torch "
        "sees a GPU; openvino needs pip install 'cnep-pipeline[openvino]')",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU threads per process for inference (default: the cores shared among the workers)",
    )
    parser.add_argument(
        "--precision",
        choices=("fp32", "int8"),
        default="fp32",
        help="fp32 (default) or int8: ONNX Runtime static quantisation calibrated on the inputs' frames "
        "(~1%% feature error, faster; never mixed with fp32 features)",
    )
    parser.add_argument(
        "--workers",
        type=_workers,
        default=1,
        help="processes extracting files side by side on this machine (default 1), or `auto`: one per "
        "core, but only as many as the job pays for (a worker takes seconds to start); under "
        "torchrun each rank extracts its share of the files",
    )
    parser.add_argument(
        "--shard",
        type=_shard,
        default=(0, 1),
        metavar="I/N",
        help="extract only the I-th of N shares of the inputs (0 <= I < N; every N-th file by output path), so "
        "that N jobs (a Slurm job array, a Kubernetes indexed job) split one data set into one --out; each "
        "calibrates random weights on every input alike (default 0/1: every file)",
    )
    parser.add_argument(
        "--calibrate-on",
        nargs="+",
        metavar="DEMO",
        default=(),
        help="demonstration files or folders whose frames calibrate random weights and quantise int8, "
        "instead of the inputs: extract later files with the first run's int8 identity",
    )
    parser.add_argument(
        "--batch-size", type=int, default=None, help="frames per forward pass (default 4 on a CPU, 64 on a GPU)"
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="re-extract outputs that are already up to date, and replace existing outputs made otherwise (other "
        "weights); only files `cnep extract` recorded writing, never a file of yours or another command's",
    )
    parser.add_argument(
        "--keep-going",
        action="store_true",
        help="skip demonstrations that fail, extract the others, and list the skipped ones at the end (exit 2)",
    )
    parser.add_argument(
        "--offline",
        action="store_true",
        help="never download the ImageNet weights (also: environment variable CNEP_OFFLINE=1)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from cnep.pipeline.inputs import DEMONSTRATIONS, mcap_files

    for given in (*args.inputs, *args.calibrate_on):  # refused before torch and onnx load with the stage
        mcap_files(Path(given), DEMONSTRATIONS)
    from cnep.pipeline.progress import heartbeat

    with heartbeat("loading torch and the extract stage", args.quiet):
        from cnep.pipeline.extract.stage import ExtractConfig, extract

    options = {"batch_size": args.batch_size} if args.batch_size is not None else {}
    config = ExtractConfig(
        inputs=tuple(Path(p) for p in args.inputs),
        out=Path(args.out),
        weights=args.weights,
        backend=args.backend,
        threads=args.threads,
        seed=args.seed,
        force=args.force,
        keep_going=args.keep_going,
        save_weights=Path(args.save_weights) if args.save_weights else None,
        quiet=args.quiet,
        offline=args.offline,
        workers=args.workers,
        precision=args.precision,
        calibrate_on=tuple(Path(p) for p in args.calibrate_on),
        shard=args.shard,
        views=args.views,
        **options,
    )
    done = extract(config)
    skipped = sum(item.skipped for item in done)
    print(
        f"extracted {len(done) - skipped} trajectory file(s) into {config.out} ({skipped} up to date, "
        f"{sum(item.n_steps for item in done)} steps)"
    )
    return 0


def _workers(text: str) -> int | str:
    """`--workers`: a whole number or `auto`."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number or `auto`, got {text!r}") from None


def _shard(text: str) -> tuple[int, int]:
    """`--shard I/N`: two whole numbers, 0 <= I < N."""
    index, _, count = text.partition("/")
    try:
        shard = int(index), int(count)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected I/N (two whole numbers, as 0/4), got {text!r}") from None
    if not 0 <= shard[0] < shard[1]:
        raise argparse.ArgumentTypeError(f"expected 0 <= I < N, got {text!r}")
    return shard
