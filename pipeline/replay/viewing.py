"""Opening a Rerun file where the user is: the native viewer on a machine with a display, else Rerun's web viewer.

Without a display (a robot PC over SSH, a cloud machine) the native viewer cannot open a window, so the file is
served instead: `rerun --serve-web --web-viewer-port WEB --port GRPC FILE` hosts the web viewer over HTTP on WEB and
the recording over gRPC on GRPC, and `web_instructions` says which address to open in a browser and, over SSH,
which ports to forward. No torch, no rerun-sdk import: the `rerun` command does the work.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from urllib.parse import quote

WEB_VIEWER_PORT = 9090  # Rerun's default for the web viewer's HTTP server
GRPC_PORT = 9876  # Rerun's default for the viewer's gRPC server
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")  # where a Linux (or BSD) desktop session says it is


def has_display() -> bool:
    """True where the native viewer can open a window: macOS and Windows always, elsewhere an X11 or Wayland session."""
    return sys.platform in ("darwin", "win32") or any(os.environ.get(name) for name in DISPLAY_VARIABLES)


def rerun_command() -> list[str]:
    """The `rerun` command of the rerun-sdk installed with this Python (its `rerun_cli` module), whether or not its
    virtual environment is activated."""
    return [sys.executable, "-m", "rerun_cli"]


def viewer_command(rrd: Path, web: bool, web_port: int = WEB_VIEWER_PORT, grpc_port: int = GRPC_PORT) -> list[str]:
    """The command that opens `rrd`: the native viewer, or with `web` the served web viewer on these ports."""
    if not web:
        return [*rerun_command(), str(rrd)]
    return [
        *rerun_command(),
        "--serve-web",
        "--web-viewer-port",
        str(web_port),
        "--port",
        str(grpc_port),
        str(rrd),
    ]


def web_url(web_port: int = WEB_VIEWER_PORT, grpc_port: int = GRPC_PORT, host: str = "localhost") -> str:
    """The address to open in a browser: the web viewer, pointed at the served recording."""
    return f"http://{host}:{web_port}/?url={quote(f'rerun+http://{host}:{grpc_port}/proxy', safe='')}"


def web_instructions(rrd: Path, web_port: int = WEB_VIEWER_PORT, grpc_port: int = GRPC_PORT) -> str:
    """What to do with a served file: the address to open, and over SSH the two ports to forward first."""
    return (
        f"no display here: serving {rrd} in Rerun's web viewer until Ctrl-C.\n"
        f"Open in a browser on this machine: {web_url(web_port, grpc_port)}\n"
        f"From another machine over SSH, forward both ports first, then open the same address there:\n"
        f"  ssh -L {web_port}:localhost:{web_port} -L {grpc_port}:localhost:{grpc_port} <user>@<this machine>"
    )
