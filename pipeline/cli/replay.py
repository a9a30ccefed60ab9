"""`cnep replay CHECKPOINT RECORDING... [--out FILE.rrd] [--connect URL | --serve]`: gate decisions in Rerun."""

from __future__ import annotations

import argparse

from cnep.pipeline.cli.export import add_conditioning, conditioning_given

HELP = "replay trajectory files through a trained CNEP: expert probabilities over time, written to a Rerun .rrd"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", help="checkpoint directory written by `cnep train`")
    parser.add_argument("recordings", nargs="+", metavar="RECORDING", help="trajectory files (read only)")
    parser.add_argument(
        "--out",
        default="replay.rrd",
        help="the .rrd file to write (default: replay.rrd); several "
        "recordings go to one file each beside it, <name>-01-<folder>-<file>.rrd, ..., which the "
        "viewer opens on that recording; the decisions go beside it as <name>.experts.json",
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="write every recording into the one --out file instead "
        "(the viewer then opens on one of them, which one is not fixed)",
    )
    live = parser.add_mutually_exclusive_group()
    live.add_argument(
        "--connect",
        metavar="URL",
        default=None,
        help="stream to the viewer at URL too, if one answers (default: the local viewer, "
        "rerun+http://127.0.0.1:9876/proxy)",
    )
    live.add_argument(
        "--serve",
        action="store_true",
        help="host a gRPC server (port --port) for viewers to connect to; keeps serving until Ctrl-C",
    )
    live.add_argument("--no-live", action="store_true", help="write the .rrd only, do not look for a viewer")
    parser.add_argument("--port", type=int, default=9876, help="port of --serve (default 9876)")
    add_conditioning(parser)
    parser.add_argument(
        "--events-out",
        metavar="DIR",
        default=None,
        help="also write copies of the recordings with the expert decisions on /events into DIR",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace existing outputs (the .rrd files, the .experts.json, the copies in --events-out; only files "
        "`cnep replay` recorded writing)",
    )


def run(args: argparse.Namespace) -> int:
    import shlex
    from pathlib import Path

    from cnep.models.checkpoint import CONFIG_FILE, read_checkpoint_config
    from cnep.pipeline.inputs import TRAJECTORIES, existing_files
    from cnep.pipeline.run.config import conditioning_line
    from cnep.pipeline.train.config import checkpoint_conditioning

    checkpoint = read_checkpoint_config(args.checkpoint)  # refused before torch and rerun load with the stage
    given = conditioning_given(args)
    own = checkpoint_conditioning(checkpoint, Path(args.checkpoint) / CONFIG_FILE)
    existing_files(args.recordings, TRAJECTORIES)
    from cnep.pipeline.progress import heartbeat

    with heartbeat("loading torch and the replay stage", args.quiet):
        from cnep.pipeline.replay.decisions import decisions_path, read_decisions
        from cnep.pipeline.replay.rerun_log import DEFAULT_VIEWER_URL, serve, serve_until_interrupted
        from cnep.pipeline.replay.stage import replay

    server = None
    connect = None if args.no_live else args.connect or DEFAULT_VIEWER_URL
    if args.serve:
        server, connect = serve(args.port)
        print(f"serving on {connect}: connect a viewer with `rerun {connect}`")
    files = replay(
        args.checkpoint,
        args.recordings,
        args.out,
        policy=given.applied(own),
        connect=connect,
        events_dir=args.events_out,
        merge=args.merge,
        force=args.force,
        quiet=args.quiet,
    )
    for rec in read_decisions(args.out)["recordings"]:
        share = ", ".join(f"{p:.0%}" for p in rec["share"])
        print(
            f"{rec['recording']}: expert {rec['majority_expert']} (steps per expert: {share}), "
            f"{len(rec['switches'])} switch(es)" + (f" -> {rec['rrd']}" if len(files) > 1 else "")
        )
    print(conditioning_line(own, given, "the checkpoint's"))
    print(
        f"wrote {files[0] if len(files) == 1 else f'{len(files)} .rrd files'} and {decisions_path(args.out)}; "
        f"open one with `cnep view {shlex.quote(str(files[0]))}`"
    )
    if server is not None:
        serve_until_interrupted()
    return 0
