"""ImageNet weights are downloaded into the torch hub cache like torchvision does, from a local HTTP server here."""

import socket
import time

import pytest

import cnep.perception.weights as weights_module
from cnep.perception import PerceptionError, resolve_weights, state_dict_sha256
from cnep.perception.constants import OFFLINE_ENV_VAR, WEIGHTS_ENV_VAR
from cnep.pipeline.cli.main import main
from cnep.recordings import write_demonstration
from tests.recordings.factories import demonstration_factory
from tests.weights_server import WeightsServer, only_weights_file


def test_missing_weights_are_downloaded_into_the_hub_cache_once(hub, served, monkeypatch):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    loaded = resolve_weights("imagenet")
    assert loaded.name == f"imagenet:{name}"
    assert sorted(p.name for p in hub.iterdir()) == [name]  # no temporary file left
    assert state_dict_sha256(loaded.state_dict) == state_dict_sha256(weights_module.load_state_dict(hub / name))
    assert resolve_weights("imagenet").name == loaded.name and server.requests == [f"/{name}"]  # cached


def test_a_download_with_the_wrong_hash_is_not_kept(hub, served, monkeypatch, tmp_path):
    server, name = served
    wrong = "mobilenet_v2-00000000.pth"
    (tmp_path / "www" / name).rename(tmp_path / "www" / wrong)
    only_weights_file(monkeypatch, wrong, f"{server.url}/{wrong}")
    with pytest.raises(PerceptionError, match="is corrupt: its sha256 .* does not start with '00000000'"):
        resolve_weights("imagenet")
    assert list(hub.iterdir()) == []


def test_without_network_the_error_names_url_cache_and_alternatives(hub, monkeypatch):
    server = WeightsServer(hub.parent)  # a port that answers nothing useful once closed
    url = f"{server.url}/mobilenet_v2-b0353104.pth"
    server.close()
    only_weights_file(monkeypatch, "mobilenet_v2-b0353104.pth", url)
    with pytest.raises(PerceptionError) as info:
        resolve_weights("imagenet")
    message = str(info.value)
    assert url in message and str(hub / "mobilenet_v2-b0353104.pth") in message
    assert WEIGHTS_ENV_VAR in message and "random" in message
    assert not hub.exists() or not any(hub.iterdir())


def test_offline_refuses_without_a_request(hub, served, monkeypatch, tmp_path, capsys):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    demo = write_demonstration(tmp_path / "d.mcap", demonstration_factory(3))
    assert main(["-q", "extract", str(demo), "--out", str(tmp_path / "out"), "--offline"]) == 2
    err = capsys.readouterr().err.strip()
    assert "downloading is off" in err and str(hub) in err and f"{server.url}/{name}" in err and "\n" not in err
    monkeypatch.setenv(OFFLINE_ENV_VAR, "1")
    with pytest.raises(PerceptionError, match="downloading is off"):
        resolve_weights("imagenet")
    assert server.requests == [] and not hub.exists()


class DroppedPackets:
    """A socket whose connect waits for its whole timeout and gives up, as where a firewall drops packets."""

    def __init__(self, *args, **kwargs) -> None:
        self.timeout = None

    def settimeout(self, seconds) -> None:
        self.timeout = seconds

    def connect(self, address) -> None:
        time.sleep(self.timeout)
        raise TimeoutError("timed out")

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def test_without_a_connection_the_download_gives_up_in_seconds(hub, monkeypatch):
    only_weights_file(monkeypatch, "mobilenet_v2-b0353104.pth", "https://weights.invalid/mobilenet_v2-b0353104.pth")
    addresses = [(socket.AF_INET, socket.SOCK_STREAM, 6, "", (f"192.0.2.{k}", 443)) for k in (1, 2, 3)]
    monkeypatch.setattr(socket, "getaddrinfo", lambda *args, **kwargs: addresses)
    monkeypatch.setattr(socket, "socket", DroppedPackets)
    monkeypatch.setattr(weights_module.connection_refused, "__defaults__", (0.5,))
    start = time.monotonic()
    with pytest.raises(PerceptionError) as info:
        resolve_weights("imagenet")
    assert time.monotonic() - start < 2  # every address together, not the read timeout per address
    message = str(info.value)
    assert "no connection to weights.invalid port 443 within" in message
    assert "--weights random" in message and "--offline" in message and WEIGHTS_ENV_VAR in message
