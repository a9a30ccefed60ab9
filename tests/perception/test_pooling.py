"""Cell pooling: what seeded random weights keep of where things stand (perception.network)."""

import numpy as np
import pytest
import torch

from cnep.perception import FeatureExtractor, PerceptionError, resize_frames
from cnep.perception.constants import ARCHITECTURES, DEFAULT_BATCH_SIZE
from cnep.perception.frames import decode_image
from cnep.perception.network import FeatureNet, mobilenet_v2_features
from cnep.perception.weights import load_weights_file, resolve_weights, save_state_dict
from cnep.pipeline.demo.generator import make_demonstration
from cnep.pipeline.demo.scene import BEHAVIOURS

PER_BEHAVIOUR = 8  # first frames of the demo's scenes per behaviour, for fitting and again for testing


def _ridge_read(train: np.ndarray, labels: np.ndarray, test: np.ndarray, lam: float = 1.0) -> np.ndarray:
    """One-hot ridge regression on standardised features: the predicted label of each test row."""
    mu, sd = train.mean(0), train.std(0) + 1e-9
    x, xt = (train - mu) / sd, (test - mu) / sd
    targets = np.eye(labels.max() + 1)[labels]
    alpha = np.linalg.solve(x @ x.T + lam * np.eye(len(x)), targets - targets.mean(0))  # dual form: rows << columns
    return (xt @ x.T @ alpha).argmax(1)


class _Once(torch.nn.Module):
    """`features` run once, a few frames a pass (DEFAULT_BATCH_SIZE, as the extractor runs them): every later call
    returns that first (N, 1280, 7, 7) map, so each pooling reads the same convolutions without recomputing them."""

    def __init__(self, features: torch.nn.Module) -> None:
        super().__init__()
        self.features, self.map = features, None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.map is None:
            self.map = torch.cat([self.features(batch) for batch in x.split(DEFAULT_BATCH_SIZE)])
        return self.map


@pytest.mark.slow
def test_cells_read_the_demo_scenes_behaviour_from_few_examples():
    # The behaviour is where the cup and the free slot are: cells keep where things stand, pooled globally only as
    # far as the low-pass kernels carry it (perception.calibration).
    seeds = np.random.SeedSequence(0).spawn(2 * PER_BEHAVIOUR * len(BEHAVIOURS))
    frames = np.stack(
        [
            decode_image(make_demonstration(i % 4, 40, 10.0, np.random.default_rng(s), "x", rendered=1).frames[0])
            for i, s in enumerate(seeds)
        ]
    )
    labels = np.arange(len(frames)) % len(BEHAVIOURS)
    half = len(frames) // 2
    extractor = FeatureExtractor("random", backend="eager", threads=1)
    extractor.calibrate(frames[:half])
    pixels = torch.from_numpy(resize_frames(frames))
    convolutions = _Once(extractor.net.features)
    accuracy = {}
    for pooling in ARCHITECTURES:
        with torch.inference_mode():
            features = FeatureNet(convolutions, pooling).eval()(pixels).numpy()  # (64, 1280)
        read = _ridge_read(features[:half], labels[:half], features[half:])
        accuracy[pooling] = (read == labels[half:]).mean()
    assert accuracy["cells"] >= 0.8 and accuracy["cells"] >= accuracy["global"], accuracy


def test_random_weights_pool_by_cells_and_their_saved_file_keeps_it(tmp_path):
    assert resolve_weights("random").pooling == "cells"
    extractor = FeatureExtractor("random", backend="eager", threads=1)
    assert extractor.identity["architecture"] == ARCHITECTURES["cells"]
    extractor.save_weights(tmp_path / "w.pt")
    assert load_weights_file(tmp_path / "w.pt")[1] == "cells"
    assert (
        FeatureExtractor(tmp_path / "w.pt", backend="eager", threads=1).identity["architecture"]
        == ARCHITECTURES["cells"]
    )


def test_weights_files_without_a_pooling_pool_globally(tmp_path):
    # Torchvision's ImageNet files, and files saved with global pooling, hold no pooling key.
    torch.save({f"features.{k}": v for k, v in mobilenet_v2_features().state_dict().items()}, tmp_path / "tv.pth")
    assert resolve_weights(tmp_path / "tv.pth").pooling == "global"
    save_state_dict(mobilenet_v2_features().state_dict(), tmp_path / "g.pt")
    assert load_weights_file(tmp_path / "g.pt")[1] == "global"
    assert (
        FeatureExtractor(tmp_path / "g.pt", backend="eager", threads=1).identity["architecture"]
        == ARCHITECTURES["global"]
    )


def test_cell_pooling_reads_one_cell_per_channel():
    class Fixed(torch.nn.Module):  # a stand-in for the convolutions: the pooling alone
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return feature_map

    feature_map = torch.randn(2, 1280, 7, 7)
    out = FeatureNet(Fixed(), "cells")(torch.zeros(2, 224, 224, 3, dtype=torch.uint8))
    cell = torch.arange(1280) % 49
    torch.testing.assert_close(out, feature_map.flatten(2)[:, torch.arange(1280), cell])


def test_unknown_pooling_is_refused(tmp_path):
    with pytest.raises(PerceptionError, match="pooling must be one of"):
        FeatureNet(mobilenet_v2_features(), "max")
    torch.save({"cnep.pooling": "max", **mobilenet_v2_features().state_dict()}, tmp_path / "bad.pt")
    with pytest.raises(PerceptionError, match="cnep.pooling is 'max'"):
        load_weights_file(tmp_path / "bad.pt")
