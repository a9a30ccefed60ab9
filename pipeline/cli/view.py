"""`cnep view FILE.rrd [--web] [--web-port P] [--port Q]`: open a Rerun file, with or without a display."""

from __future__ import annotations

import argparse

HELP = (
    "open a .rrd file: the Rerun viewer where there is a display, else Rerun's web viewer served on this machine, "
    "with the address to open in a browser (over SSH: the ports to forward)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from cnep.pipeline.replay.viewing import GRPC_PORT, WEB_VIEWER_PORT

    parser.add_argument("rrd", metavar="FILE", help="the .rrd file (cnep demo, cnep replay and cnep run write them)")
    parser.add_argument("--web", action="store_true", help="serve the web viewer even where there is a display")
    parser.add_argument(
        "--web-port", type=int, default=WEB_VIEWER_PORT, help=f"the web viewer's HTTP port (default {WEB_VIEWER_PORT})"
    )
    parser.add_argument(
        "--port", type=int, default=GRPC_PORT, help=f"the port the recording is served on (default {GRPC_PORT})"
    )


def run(args: argparse.Namespace) -> int:
    """Run the viewer in the foreground: its exit status, or 0 when the web viewer is stopped with Ctrl-C."""
    import subprocess
    from pathlib import Path

    from cnep.pipeline.inputs import existing_files
    from cnep.pipeline.replay.viewing import has_display, viewer_command, web_instructions

    rrd = Path(args.rrd)
    existing_files([rrd], "a .rrd file")
    web = args.web or not has_display()
    if web:
        print(web_instructions(rrd, args.web_port, args.port), flush=True)
    try:
        return subprocess.run(viewer_command(rrd, web, args.web_port, args.port)).returncode
    except KeyboardInterrupt:
        return 0
