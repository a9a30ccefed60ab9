"""`cnep run POLICY RECORDING... (--out FILE.rrd | --connect [URL] | --serve)`: a dry run of the robot loop."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.export import add_conditioning, add_time_base, conditioning_given
from cnep.pipeline.cli.fields import default_of, help_of
from cnep.pipeline.run.config import RunConfig
from cnep.runtime.constants import BACKENDS, FEATURES_FILES

HELP = "run a policy (exported folder or checkpoint) over demonstration recordings, step by step, into Rerun"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("policy", help="a folder written by `cnep export` (runs without torch) or `cnep train`")
    parser.add_argument(
        "recordings",
        nargs="+",
        metavar="RECORDING",
        help="demonstration files or folders of them (with camera frames for a policy that sees)",
    )
    sink = parser.add_mutually_exclusive_group(required=True)
    sink.add_argument(
        "--out",
        metavar="FILE.rrd",
        help="write the run to this .rrd (several recordings: one file each beside it) and the summary to "
        "<name>.summary.json",
    )
    sink.add_argument(
        "--connect",
        metavar="URL",
        nargs="?",
        const="",
        help="stream live to the viewer at URL (without URL: the local viewer, rerun+http://127.0.0.1:9876/proxy)",
    )
    sink.add_argument("--serve", action="store_true", help="host a gRPC server (port --port) for viewers to join")
    parser.add_argument("--port", type=int, default=9876, help="port of --serve (default 9876)")
    parser.add_argument(
        "--fast", action="store_true", help="step as fast as possible instead of at the recording's rate"
    )
    parser.add_argument("--extractor", metavar="FILE", help="a checkpoint's feature weights (as `cnep export` takes)")
    parser.add_argument(
        "--precision", choices=tuple(FEATURES_FILES), default=default_of(RunConfig, "precision"),
        help=help_of(RunConfig, "precision"),
    )  # fmt: skip
    parser.add_argument(
        "--backend", choices=BACKENDS, default=default_of(RunConfig, "backend"), help=help_of(RunConfig, "backend")
    )
    parser.add_argument(
        "--threads", type=int, default=default_of(RunConfig, "threads"),
        help=help_of(RunConfig, "threads", default="one per core"),
    )  # fmt: skip
    parser.add_argument(
        "--waypoints", type=int, default=default_of(RunConfig, "waypoints"), help=help_of(RunConfig, "waypoints")
    )
    add_time_base(parser, "default: the policy's own")
    add_conditioning(parser)
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace existing outputs (the .rrd files, the summary; only files `cnep run` recorded writing)",
    )


def run(args: argparse.Namespace) -> int:
    import shlex
    from pathlib import Path

    from cnep.pipeline.inputs import existing_files, find_demonstration_files
    from cnep.pipeline.run.config import conditioning_line, own_conditioning, policy_kind

    policy_kind(args.policy)  # the paths are refused before torch or rerun load with the stage
    find_demonstration_files(args.recordings)
    if args.extractor:
        existing_files([args.extractor], "the weights file the training features were made with")
    from cnep.pipeline.replay.rerun_log import DEFAULT_VIEWER_URL, serve_until_interrupted
    from cnep.pipeline.run.stage import format_summary, run, summarise, summary_path

    server = None
    connect = args.connect or (DEFAULT_VIEWER_URL if args.connect is not None else None)
    if args.serve:
        from cnep.pipeline.replay.rerun_log import serve

        server, connect = serve(args.port)
        print(f"serving on {connect}: connect a viewer with `rerun {connect}`")
    config = RunConfig(
        policy=Path(args.policy),
        recordings=tuple(Path(p) for p in args.recordings),
        out=Path(args.out) if args.out else None,
        connect=connect,
        extractor=Path(args.extractor) if args.extractor else None,
        precision=args.precision,
        backend=args.backend,
        threads=args.threads,
        waypoints=args.waypoints,
        time_base=args.time_base,
        conditioning=conditioning_given(args),
        realtime=not args.fast,
        force=args.force,
        quiet=args.quiet,
    )
    runs = run(config)
    print(format_summary(summarise(runs)))
    print(conditioning_line(own_conditioning(config.policy), config.conditioning))
    if args.out:
        from cnep.pipeline.replay.rerun_log import rrd_files

        files = rrd_files(Path(args.out), [r.path for r in runs], merge=False)
        wrote = files[0] if len(files) == 1 else f"{len(files)} .rrd files, one per recording, beside {args.out}"
        print(f"wrote {wrote} and {summary_path(args.out)}; open one with `cnep view {shlex.quote(str(files[0]))}`")
    if server is not None:
        serve_until_interrupted()
    return 0
