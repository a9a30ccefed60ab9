"""`cnep view`: the native Rerun viewer where there is a display, else the web viewer served with its address."""

import os
import socket
import subprocess
import sys
import time
import urllib.request

import pytest

from cnep.pipeline.demo.stage import RRD_FILE
from cnep.pipeline.replay import viewing


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_display_is_found_from_the_session(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    for name in viewing.DISPLAY_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    assert not viewing.has_display()
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert viewing.has_display()


def test_the_native_viewer_opens_the_file_itself(tmp_path):
    assert viewing.viewer_command(tmp_path / "a.rrd", web=False) == [*viewing.rerun_command(), str(tmp_path / "a.rrd")]


def test_without_a_display_the_file_is_served_to_a_browser(quick_demo, tmp_path):
    web, grpc = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if k not in viewing.DISPLAY_VARIABLES}
    env.update(HOME=str(tmp_path), CI="1")  # the rerun CLI writes analytics under HOME unless CI is set
    command = [sys.executable, "-m", "cnep.pipeline.cli.main", "view", str(quick_demo / RRD_FILE)]
    served = subprocess.Popen(
        [*command, "--web-port", str(web), "--port", str(grpc)], env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        said = [served.stdout.readline() for _ in range(4)]
        assert said[0].startswith("no display here: serving") and viewing.web_url(web, grpc) in said[1]
        assert f"ssh -L {web}:localhost:{web} -L {grpc}:localhost:{grpc}" in said[3]
        deadline = time.monotonic() + 60
        while True:  # the web viewer's page, once the server is up
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=5) as page:
                    assert page.status == 200 and b"<html" in page.read().lower()
                break
            except OSError:
                assert time.monotonic() < deadline and served.poll() is None, "the web viewer did not start"
                time.sleep(0.5)
    finally:
        served.terminate()
        served.wait(timeout=30)
    with pytest.raises(OSError):  # stopping `cnep view` stopped the viewer it started, binary included
        urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=5)
