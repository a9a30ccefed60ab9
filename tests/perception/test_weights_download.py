"""ImageNet weights are downloaded into the torch hub cache like torchvision does, from a local HTTP server here."""

import hashlib
import http.server
import threading
from functools import partial

import pytest
import torch
from torchvision.models import mobilenet_v2

import cnep.perception.weights as weights_module
from cnep.perception import PerceptionError, resolve_weights, state_dict_sha256
from cnep.perception.constants import OFFLINE_ENV_VAR, WEIGHTS_ENV_VAR
from cnep.pipeline.cli.main import main
from cnep.recordings import write_demonstration
from tests.recordings.factories import demonstration_factory


class _Server:
    """Serves the files of a folder on 127.0.0.1 and counts the requests."""

    def __init__(self, folder):
        self.requests = []
        server = self

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                server.requests.append(self.path)
                super().do_GET()

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), partial(Handler, directory=str(folder)))
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def hub(tmp_path, monkeypatch):
    """An empty torch hub cache, downloads allowed, no environment override."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv(WEIGHTS_ENV_VAR, raising=False)
    monkeypatch.delenv(OFFLINE_ENV_VAR, raising=False)
    return tmp_path / "torch" / "hub" / "checkpoints"


@pytest.fixture
def served(tmp_path):
    """A seeded full MobileNet-v2 state dict, served as torchvision names its files (-<sha256 prefix>.pth)."""
    folder = tmp_path / "www"
    folder.mkdir()
    torch.manual_seed(11)
    torch.save(mobilenet_v2(weights=None).state_dict(), folder / "weights.pth")
    prefix = hashlib.sha256((folder / "weights.pth").read_bytes()).hexdigest()[:8]
    name = f"mobilenet_v2-{prefix}.pth"
    (folder / "weights.pth").rename(folder / name)
    server = _Server(folder)
    yield server, name
    server.close()


def _only_file(monkeypatch, name, url):
    monkeypatch.setattr(weights_module, "IMAGENET_WEIGHT_FILES", {name: url})


def test_missing_weights_are_downloaded_into_the_hub_cache_once(hub, served, monkeypatch):
    server, name = served
    _only_file(monkeypatch, name, f"{server.url}/{name}")
    loaded = resolve_weights("imagenet")
    assert loaded.name == f"imagenet:{name}"
    assert sorted(p.name for p in hub.iterdir()) == [name]  # no temporary file left
    assert state_dict_sha256(loaded.state_dict) == state_dict_sha256(weights_module.load_state_dict(hub / name))
    assert resolve_weights("imagenet").name == loaded.name and server.requests == [f"/{name}"]  # cached


def test_a_download_with_the_wrong_hash_is_not_kept(hub, served, monkeypatch, tmp_path):
    server, name = served
    wrong = "mobilenet_v2-00000000.pth"
    (tmp_path / "www" / name).rename(tmp_path / "www" / wrong)
    _only_file(monkeypatch, wrong, f"{server.url}/{wrong}")
    with pytest.raises(PerceptionError, match="is corrupt: its sha256 .* does not start with '00000000'"):
        resolve_weights("imagenet")
    assert list(hub.iterdir()) == []


def test_without_network_the_error_names_url_cache_and_alternatives(hub, monkeypatch):
    server = _Server(hub.parent)  # a port that answers nothing useful once closed
    url = f"{server.url}/mobilenet_v2-b0353104.pth"
    server.close()
    _only_file(monkeypatch, "mobilenet_v2-b0353104.pth", url)
    with pytest.raises(PerceptionError) as info:
        resolve_weights("imagenet")
    message = str(info.value)
    assert url in message and str(hub / "mobilenet_v2-b0353104.pth") in message
    assert WEIGHTS_ENV_VAR in message and "random" in message
    assert not any(hub.iterdir())


def test_offline_refuses_without_a_request(hub, served, monkeypatch, tmp_path, capsys):
    server, name = served
    _only_file(monkeypatch, name, f"{server.url}/{name}")
    demo = write_demonstration(tmp_path / "d.mcap", demonstration_factory(3))
    assert main(["-q", "extract", str(demo), "--out", str(tmp_path / "out"), "--offline"]) == 2
    err = capsys.readouterr().err.strip()
    assert "downloading is off" in err and str(hub) in err and f"{server.url}/{name}" in err and "\n" not in err
    monkeypatch.setenv(OFFLINE_ENV_VAR, "1")
    with pytest.raises(PerceptionError, match="downloading is off"):
        resolve_weights("imagenet")
    assert server.requests == [] and not hub.exists()
