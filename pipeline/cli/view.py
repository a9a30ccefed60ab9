"""`cnep view FILE.rrd [--web] [--web-port P] [--port Q]`: open a Rerun file, with or without a display."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess

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
    from pathlib import Path

    from cnep.pipeline.inputs import existing_files
    from cnep.pipeline.replay.viewing import has_display, viewer_command, web_instructions

    rrd = Path(args.rrd)
    existing_files([rrd], "a .rrd file")
    web = args.web or not has_display()
    if web:
        print(web_instructions(rrd, args.web_port, args.port), flush=True)
    # In a session of its own, so that stopping this command stops the viewer and every process it started (the
    # rerun wrapper runs the viewer's binary as a child, which would outlive a wrapper killed alone).
    viewer = subprocess.Popen(viewer_command(rrd, web, args.web_port, args.port), start_new_session=True)
    try:
        return viewer.wait()
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (pipeline.contract): the viewer's end, not an error
        return 0
    finally:
        _stop(viewer)


def _stop(viewer: subprocess.Popen) -> None:
    """End the viewer's whole process group (the wrapper and the binary it started): SIGTERM, then SIGKILL for
    whatever is left a few seconds later."""
    for signum in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):  # the group has ended
            os.killpg(viewer.pid, signum)
        with contextlib.suppress(subprocess.TimeoutExpired):
            viewer.wait(timeout=5)
