"""The demo's feature weights: ImageNet's wherever they can be had (the hub cache, a download from a local server
here), seeded random weights otherwise, with one warning saying why; `imagenet` refuses instead of falling back."""

import logging

import pytest
import torch
from torchvision.models import mobilenet_v2

from cnep.perception import PerceptionError
from cnep.perception.constants import IMAGENET_WEIGHT_FILES, OFFLINE_ENV_VAR, WEIGHTS_ENV_VAR
from cnep.pipeline.cli.main import main
from cnep.pipeline.demo.report import features_line
from cnep.pipeline.demo.weights import WeightsChoice, choose_weights
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.extract.stage import ExtractConfig, build_extractor
from tests.weights_server import WeightsServer, only_weights_file

LOGGER = "cnep.pipeline.demo.weights"
OFF = "none in the torch hub cache and downloading is off"
FAILED = "none in the torch hub cache and the download failed"


def _records(caplog, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno == level]


def _imagenet_stand_in(hub) -> str:
    """A full MobileNet-v2 state dict (seeded random values) in the hub cache under the first ImageNet file name."""
    name = next(iter(IMAGENET_WEIGHT_FILES))
    hub.mkdir(parents=True)
    torch.manual_seed(0)
    torch.save(mobilenet_v2(weights=None).state_dict(), hub / name)
    return name


@pytest.mark.parametrize("how", ["environment", "demo option"])
def test_auto_offline_falls_back_to_random_weights_with_one_warning(hub, served, monkeypatch, caplog, how):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    if how == "environment":
        monkeypatch.setenv(OFFLINE_ENV_VAR, "1")
    with caplog.at_level(logging.INFO, logger=LOGGER):
        chosen = choose_weights("auto", offline=how == "demo option")
    assert chosen == WeightsChoice("random", OFF)
    (warning,) = _records(caplog, logging.WARNING)
    assert "seeded random weights" in warning and "downloading is off" in warning  # why
    assert str(hub) in warning and f"{server.url}/{name}" in warning and WEIGHTS_ENV_VAR in warning  # how to get them
    assert "\n" not in warning and _records(caplog, logging.INFO) == []  # no download announced: none is tried
    assert server.requests == [] and not hub.exists()


def test_auto_takes_imagenet_weights_from_the_hub_cache_and_they_are_not_calibrated(hub, monkeypatch, caplog, tmp_path):
    name = _imagenet_stand_in(hub)
    monkeypatch.setenv(OFFLINE_ENV_VAR, "1")  # a cached file needs no download
    with caplog.at_level(logging.INFO, logger=LOGGER):
        chosen = choose_weights("auto")
    assert chosen == WeightsChoice("imagenet") and _records(caplog, logging.WARNING) == []
    # what the demo's extract stage then builds: used as given (calibration is for random weights, and with no
    # frames to calibrate on it would fail)
    config = ExtractConfig(inputs=(), out=tmp_path / "out", weights=chosen.weights, backend="eager", offline=True)
    extractor = build_extractor(config, sources=[])
    assert extractor.identity["weights"] == f"imagenet:{name}" and not extractor.needs_calibration


def test_auto_downloads_imagenet_weights_when_allowed(hub, served, monkeypatch, caplog):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    with caplog.at_level(logging.INFO, logger=LOGGER):
        chosen = choose_weights("auto")
    assert chosen == WeightsChoice("imagenet") and _records(caplog, logging.WARNING) == []
    assert server.requests == [f"/{name}"] and sorted(p.name for p in hub.iterdir()) == [name]
    before, after = _records(caplog, logging.INFO)  # said before trying: a download can take long to fail
    assert "looking for ImageNet weights" in before and str(hub) in before and "--offline" in before
    assert after == f"the features come from ImageNet weights: {hub / name}"


@pytest.mark.parametrize("failure", ["not found", "corrupt", "no server"])
def test_a_failing_download_falls_back_with_the_reason(hub, served, monkeypatch, caplog, tmp_path, failure):
    server, name = served
    said = {"not found": "File not found", "corrupt": "is corrupt", "no server": "cannot download"}[failure]
    if failure == "not found":
        name = "mobilenet_v2-0123abcd.pth"  # not on the server
    elif failure == "corrupt":
        (tmp_path / "www" / name).rename(tmp_path / "www" / "mobilenet_v2-00000000.pth")
        name = "mobilenet_v2-00000000.pth"  # its sha256 does not start with the name's digits
    else:
        server.close()
        server = WeightsServer(tmp_path / "www")
        server.close()  # a port nothing answers on
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    with caplog.at_level(logging.INFO, logger=LOGGER):
        chosen = choose_weights("auto")
    assert chosen == WeightsChoice("random", FAILED)
    (warning,) = _records(caplog, logging.WARNING)
    assert said in warning and f"{server.url}/{name}" in warning and WEIGHTS_ENV_VAR in warning
    assert not hub.exists() or not any(hub.iterdir())  # nothing half-downloaded kept (no connection: no folder)


def test_a_missing_file_named_by_the_environment_is_the_reason(hub, tmp_path, monkeypatch, caplog):
    monkeypatch.setenv(WEIGHTS_ENV_VAR, str(tmp_path / "nope.pth"))
    with caplog.at_level(logging.INFO, logger=LOGGER):
        assert choose_weights("auto") == WeightsChoice("random", f"{WEIGHTS_ENV_VAR} is not a file")
    (warning,) = _records(caplog, logging.WARNING)
    assert "nope.pth is not a file" in warning


def test_imagenet_is_refused_instead_of_falling_back(hub, served, monkeypatch, caplog):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    with caplog.at_level(logging.INFO, logger=LOGGER), pytest.raises(PerceptionError, match="downloading is off"):
        choose_weights("imagenet", offline=True)
    assert _records(caplog, logging.WARNING) == [] and server.requests == []
    assert choose_weights("imagenet") == WeightsChoice("imagenet") and server.requests == [f"/{name}"]


def test_random_and_a_file_are_taken_as_given(hub, served, monkeypatch, tmp_path):
    server, name = served
    only_weights_file(monkeypatch, name, f"{server.url}/{name}")
    assert choose_weights("random") == WeightsChoice("random")
    mine = tmp_path / "www" / name
    assert choose_weights(str(mine)) == WeightsChoice(str(mine))
    assert server.requests == []  # neither looks for ImageNet weights
    with pytest.raises(PerceptionError, match="absent.pth does not exist"):
        choose_weights(str(tmp_path / "absent.pth"))
    (tmp_path / "notes.pth").write_text("not weights")
    with pytest.raises(PerceptionError, match="cannot load weights file .*notes.pth"):
        choose_weights(str(tmp_path / "notes.pth"))


def test_the_demo_extracts_with_the_chosen_weights(hub, tmp_path, monkeypatch):
    from cnep.pipeline.demo import stage

    def stop(workers, **_):  # at training: only the extract calls matter here
        raise PipelineError("stopped before training")

    _imagenet_stand_in(hub)
    configs = []
    monkeypatch.setattr(stage, "extract", lambda config: configs.append(config) or [])
    monkeypatch.setattr(stage, "single_thread_processes", stop)
    assert main(["-q", "demo", "--out", str(tmp_path / "run"), "--quick", "--offline"]) == 2
    first, *others = configs
    assert first.weights == "imagenet" and first.save_weights == tmp_path / "run" / "extractor.pt"
    assert {c.weights for c in others} == {str(first.save_weights)} and all(c.offline for c in configs)


def test_imagenet_weights_that_cannot_be_had_stop_the_demo_before_it_makes_anything(hub, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["-q", "demo", "--out", str(out), "--quick", "--weights", "imagenet", "--offline"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("cnep demo: error: ImageNet weights for MobileNet-v2 not found and downloading is off")
    assert not out.exists() or list(out.iterdir()) == []


def test_the_summary_line_says_which_weights_and_why_not_imagenet():
    random = "random:seed=0+calibrated:bias=3.0,frames=256"
    line = features_line(random, OFF)
    assert line == (
        "features: MobileNet-v2 with seeded random weights calibrated on the training frames, ImageNet weights not "
        f"available: {OFF} ({random})"
    )
    assert "as asked (--weights random)" in features_line(random, None)
    assert features_line("imagenet:mobilenet_v2-b0353104.pth", None) == (
        "features: MobileNet-v2 with ImageNet weights (imagenet:mobilenet_v2-b0353104.pth)"
    )
