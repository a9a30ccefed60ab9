"""Stand-ins for the ImageNet weights' download server: a local HTTP server on 127.0.0.1 (no internet in the tests)."""

from __future__ import annotations

import hashlib
import http.server
import threading
from functools import partial
from pathlib import Path

import torch
from torchvision.models import mobilenet_v2

import cnep.perception.weights as weights_module

POLL_S = 0.05  # how often the server checks whether it should stop (s)


class WeightsServer:
    """Serves the files of a folder on 127.0.0.1 and counts the requests."""

    def __init__(self, folder: Path) -> None:
        self.requests: list[str] = []
        server = self

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                server.requests.append(self.path)
                super().do_GET()

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), partial(Handler, directory=str(folder)))
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        # polled often: `close` waits for the serving loop to notice, a poll interval at most
        threading.Thread(target=self.httpd.serve_forever, args=(POLL_S,), daemon=True).start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def torchvision_named_weights(folder: Path, seed: int = 11) -> str:
    """Save a seeded full MobileNet-v2 state dict in `folder` as torchvision names its files
    (`mobilenet_v2-<first 8 hex digits of its sha256>.pth`); returns the name."""
    folder.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    torch.save(mobilenet_v2(weights=None).state_dict(), folder / "weights.pth")
    name = f"mobilenet_v2-{hashlib.sha256((folder / 'weights.pth').read_bytes()).hexdigest()[:8]}.pth"
    (folder / "weights.pth").rename(folder / name)
    return name


def only_weights_file(monkeypatch, name: str, url: str) -> None:
    """Make `name` at `url` the one ImageNet weights file that is looked for and downloaded."""
    monkeypatch.setattr(weights_module, "IMAGENET_WEIGHT_FILES", {name: url})
